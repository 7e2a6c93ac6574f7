"""The files of an odom run: the TUM trajectory with ``.metrics.json`` and ``.config.yaml`` beside it."""

from __future__ import annotations

from pathlib import Path

from ...io.files.trajectory import format_tum
from ..outputs import write_run
from .job import OdomResult


def write_odom(result: OdomResult, out: Path, force: bool) -> None:
    """The odom run's TUM trajectory, resolved config and metrics."""
    result.metrics["output"] = str(out)
    write_run(out, format_tum(result.trajectory.stamps_ns, result.trajectory.poses), result.config,
              result.metrics, force)


__all__ = ["write_odom"]
