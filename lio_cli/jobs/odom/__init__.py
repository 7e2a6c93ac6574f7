"""``lio odom``: the job, its inputs (topics, extrinsics, clocks) and its run.

``COMMAND``: ``OdomJob`` -> ``run_odom`` -> ``score_odom`` (with ``--gt``) -> ``write_odom``.
"""

from ...config.odom import OdomConfig
from ..contract import Command
from .job import DivergedRun, OdomJob, OdomResult, run_odom, score_odom
from .outputs import TAG, map_outputs, write_odom, write_odom_map, write_odom_plots


def _key_metrics(metrics: dict) -> dict:
    scans = metrics["scans"]
    return {"scans_total": scans["total"], "scans_used": scans["used"], "span_s": metrics.get("trajectory_span_s")}


COMMAND = Command(
    name="odom", config=OdomConfig, job=lambda log, config, out: OdomJob(log, config), run=run_odom,
    write=write_odom, score=score_odom, tag=TAG, output=lambda folder, log, config: folder / f"{TAG}.tum",
    key_metrics=_key_metrics, threads=lambda config: config.registration.threads,
)

__all__ = ["COMMAND", "TAG", "DivergedRun", "OdomJob", "OdomResult", "map_outputs", "run_odom", "score_odom",
           "write_odom", "write_odom_map", "write_odom_plots"]
