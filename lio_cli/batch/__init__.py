"""``lio batch``: many runs of the single commands' jobs (manifest, executors, summary); no printing here.

``manifest`` (what to run) -> ``runner.plan_batch`` (jobs resolved, output root checked) -> ``runner.run_batch``
on an ``executors.Executor`` (this process, local processes, Dask) calling ``runs.execute`` per run ->
``summary`` (summary.json, summary.csv, group statistics).
"""

from .executors import Executor, choose_executor
from .manifest import Manifest, RunSpec, expand, load_manifest, shorthand
from .runner import plan_batch, run_batch
from .runs import RunTask, execute
from .summary import Summary

__all__ = ["Executor", "Manifest", "RunSpec", "RunTask", "Summary", "choose_executor", "execute", "expand",
           "load_manifest", "plan_batch", "run_batch", "shorthand"]
