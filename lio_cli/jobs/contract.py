"""The contract every command keeps: ``Job`` -> ``run(job, progress) -> Result`` -> ``score(result, reference)``
(where ground truth applies) -> ``write(result, out, force)``.

Each command's package names its steps in a ``Command`` record (``jobs.odom.COMMAND`` ...): ``lio batch`` is a
table over these records and the CLI calls the same functions, so no caller needs a branch per command.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from pydantic import BaseModel

from ..model.trajectory import Trajectory

Progress = Callable[[int, int | None], None]  # (work done, total work or None)


@dataclass(frozen=True)
class Command:
    """One command's steps and what a batch needs to know of it."""

    name: str
    config: type[BaseModel]  # the configuration model
    job: Callable[[Path, Any, Path], Any]  # (log, resolved config, main output) -> the job a batch run runs
    run: Callable[..., Any]  # (job, progress=None) -> result (with ``.metrics``); writes nothing it need not stream
    write: Callable[[Any, Path | None, bool], list[Path]]  # (result, main output, force): the run's files, written
    score: Callable[[Any, Trajectory], None] | None  # (result, reference): accuracy into the result; None: no trajectory
    tag: str  # every file of a run carries it (walk.odom.tum, walk.odom.metrics.json; side_file); a batch run's
    # folder holds TAG.tum (or .yaml, .bag ...), TAG.metrics.json and TAG.config.yaml
    output: Callable[[Path, Path, Any], Path]  # (run folder, log, config) -> the main output in a batch run's folder
    key_metrics: Callable[[dict], dict]  # the batch summary's columns this command fills from its metrics
    threads: Callable[[Any], int | None]  # kiss-icp threads its registrations ask for (None: it registers none)
    calibration_field: str = "calibration"  # the configuration field a --calib file fills

    def metrics_file(self) -> str:
        return f"{self.tag}.metrics.json"


def load_reference(log: Path, gt: str) -> Trajectory:
    """The ground truth ``gt`` (a TUM/KITTI file, or a topic of ``log``) named as given. Read before the run: a bad
    one is bad input before the work, not after it."""
    from ..io.sensors.sources import load_ground_truth  # loaded only by a run that has a reference

    ref = load_ground_truth(log, gt)
    return Trajectory(ref.stamps_ns, ref.poses, gt)


def score_into(result: Any, reference: Trajectory, name: str) -> None:
    """ATE/RPE of ``result.trajectory`` (called ``name`` in messages) against ``reference``, as ``result.score`` and
    ``result.metrics["accuracy"]``."""
    from ..evaluation.scoring import score  # loaded only by a run that has a reference

    est = result.trajectory
    result.score = score(reference, Trajectory(est.stamps_ns, est.poses, name))
    result.metrics["accuracy"] = result.score.to_dict()


__all__ = ["Command", "Progress", "load_reference", "score_into"]
