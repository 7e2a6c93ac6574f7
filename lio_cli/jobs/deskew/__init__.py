"""``lio deskew``: the job, the motion source, per-scan de-skew, the writer and its helper process.

``COMMAND``: ``DeskewJob`` -> ``run_deskew`` (streams the output log) -> ``write_deskew`` (its metrics and config).
"""

from ...config.deskew import DeskewConfig
from ..contract import Command
from .job import TAG, DeskewJob, DeskewResult, check_deskew_outputs, output_in, run_deskew, write_deskew


def _key_metrics(metrics: dict) -> dict:
    scans = metrics["scans"]
    return {"scans_total": scans["total"], "scans_used": scans["deskewed"], "span_s": metrics.get("log_duration_s")}


def _threads(config: DeskewConfig) -> int | None:
    return None if config.trajectory.path is not None else config.odometry.registration.threads


COMMAND = Command(
    # a batch already keeps every core busy with one log each: no second process per log
    name="deskew", config=DeskewConfig, job=lambda log, config, out: DeskewJob(log, out, config, helper=False),
    run=run_deskew, write=write_deskew, score=None, tag=TAG, output=output_in, key_metrics=_key_metrics,
    threads=_threads,
)

__all__ = ["COMMAND", "TAG", "DeskewJob", "DeskewResult", "check_deskew_outputs", "output_in", "run_deskew",
           "write_deskew"]
