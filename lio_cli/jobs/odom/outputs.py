"""The files of an odom run: the TUM trajectory with ``NAME.odom.metrics.json`` and ``NAME.odom.config.yaml``
beside it."""

from __future__ import annotations

from pathlib import Path

from ...io.files.trajectory import format_tum
from ..outputs import write_run
from .job import OdomResult

TAG = "odom"  # in the name of every file a run writes


def write_odom(result: OdomResult, out: Path, force: bool) -> list[Path]:
    """The odom run's TUM trajectory, resolved config and metrics; returns the paths written."""
    result.metrics["output"] = str(out)
    return write_run(out, TAG, format_tum(result.trajectory.stamps_ns, result.trajectory.poses), result.config,
              result.metrics, force)


__all__ = ["TAG", "write_odom"]
