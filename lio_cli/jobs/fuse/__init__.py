"""``lio fuse``: the job, its sources, the chunked fusion and the files it writes.

``COMMAND``: ``FuseJob`` -> ``run_fuse`` -> ``score_fuse`` (with ground truth) -> ``write_fuse``.
"""

from ...config.fuse import FuseConfig
from ..contract import Command
from .job import FuseJob, FuseRun, run_fuse, score_fuse
from .outputs import TAG, check_fuse_outputs, write_fuse

COMMAND = Command(
    name="fuse", config=FuseConfig, job=lambda log, config, out: FuseJob(log, config), run=run_fuse,
    write=write_fuse, score=score_fuse, tag=TAG, output=lambda folder, log, config: folder / f"{TAG}.tum",
    key_metrics=lambda metrics: {"poses": metrics["output"]["poses"]}, threads=lambda config: None,
)

__all__ = ["COMMAND", "TAG", "FuseJob", "FuseRun", "check_fuse_outputs", "run_fuse", "score_fuse", "write_fuse"]
