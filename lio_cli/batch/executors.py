"""Where the runs of a batch run: this process, a pool of local processes, or a Dask cluster.

Each executor calls ``execute(task)`` once per task and hands each record to ``done(record)`` as it comes
back (in completion order). A run that fails is a record like any other; a worker that disappears becomes a
``worker-lost`` record. On Ctrl-C the runs still queued are cancelled, the running ones interrupted (local) or
left to finish or die with their worker (Dask; their partial folders never become run folders), and the
interruption propagates.
"""

from __future__ import annotations

import logging
import multiprocessing
import os
import signal
import uuid
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from concurrent.futures import ProcessPoolExecutor, as_completed
from concurrent.futures.process import BrokenProcessPool
from dataclasses import dataclass

from ..cpus import usable_cpus
from ..errors import ConfigError, InputError
from .commands import registration_threads
from .runs import RunTask, execute, pool_initializer, record

Done = Callable[[dict], None]
DASK_INSTALL = ("--dask needs the optional Dask dependency: pip install 'lio-cli[dask]' "
                "(or pip install 'dask[distributed]')")
DASK_RETRIES = 1  # a task whose worker was lost (or that raised on the worker) runs once more, then fails


@dataclass(frozen=True)
class Executor:
    """``kind``: serial | local | dask; ``workers``: processes (local, dask local); ``address``: scheduler."""

    kind: str
    workers: int = 1
    address: str | None = None

    def describe(self) -> str:
        if self.kind == "serial":
            return "this process"
        if self.kind == "local":
            return f"{self.workers} local process{'es' * (self.workers != 1)}"
        if self.address == "local":
            return f"a local Dask cluster of {self.workers} worker{'s' * (self.workers != 1)}"
        return f"the Dask scheduler at {self.address}"

    @contextmanager
    def open(self) -> Iterator[Callable[[list[RunTask], Done], None]]:
        """Connect (Dask: to the scheduler, or start the local cluster) and yield ``run(tasks, done)``; an
        unreachable scheduler is an ``InputError`` here, before anything is written."""
        if self.kind == "serial":
            yield _run_here
        elif self.kind == "local":
            yield lambda tasks, done: _run_pool(tasks, self.workers, done)
        else:
            with _dask_client(self.address, self.workers) as client:
                yield lambda tasks, done: _run_dask(client, tasks, done)


def _run_here(tasks: list[RunTask], done: Done) -> None:
    """In this process, unless the runs need processes of their own (``_mixed_threads``): then one at a time,
    each in a fresh one."""
    if _mixed_threads(tasks):
        return _run_pool(tasks, 1, done)
    for task in tasks:
        done(execute(task))


def _mixed_threads(tasks: list[RunTask]) -> bool:
    """Runs whose registrations ask for different kiss-icp thread counts. kiss-icp keeps the count of a
    process's first registration, so each such run needs a fresh process to register as its command alone
    would (calibrate's 1 thread is what makes its result repeat exactly)."""
    return len({registration_threads(t.command, t.config) for t in tasks} - {None}) > 1


def choose_executor(jobs: int | None, dask: str | None, workers: int | None) -> Executor:
    """The executor the flags ask for (bad combinations are usage errors, exit 2)."""
    if dask is None:
        if workers is not None:
            raise ConfigError("--workers goes with --dask local; for local processes use --jobs N")
        n = usable_cpus() if jobs is None else jobs
        if n < 1:
            raise ConfigError(f"--jobs must be 1 or more, got {n}")
        return Executor("serial" if n == 1 else "local", n)
    if jobs is not None:
        raise ConfigError("--jobs and --dask exclude each other: with --dask the cluster's workers run the logs")
    dask_available()
    if dask == "local":
        n = usable_cpus() if workers is None else workers
        if n < 1:
            raise ConfigError(f"--workers must be 1 or more, got {n}")
        return Executor("dask", n, "local")
    if workers is not None:
        raise ConfigError("--workers goes with --dask local; a running cluster has its own workers")
    if "://" not in dask:
        raise ConfigError(f"--dask takes a scheduler address (tcp://HOST:8786) or 'local', got '{dask}'")
    return Executor("dask", 0, dask)


def dask_available() -> None:
    try:
        import distributed  # noqa: F401
    except ImportError as err:
        raise ConfigError(DASK_INSTALL) from err


def _run_pool(tasks: list[RunTask], workers: int, done: Done) -> None:
    """Run on a pool of local processes. A process that dies (killed, out of memory) breaks the pool and every
    run it still held; those runs get one more try on a fresh pool (as Dask retries a lost worker's task once),
    then are recorded as ``worker-lost``."""
    lost = _pool_pass(tasks, workers, done, final=False)
    if lost:
        _pool_pass(lost, workers, done, final=True)


def _pool_pass(tasks: list[RunTask], workers: int, done: Done, final: bool) -> list[RunTask]:
    # spawn: the workers start clean (no copy of this process's threads, e.g. the progress bar's)
    ctx = multiprocessing.get_context("spawn")
    stop = ctx.Event()
    pool = ProcessPoolExecutor(max_workers=min(workers, len(tasks)), mp_context=ctx, initializer=pool_initializer,
                               initargs=(stop,), max_tasks_per_child=1 if _mixed_threads(tasks) else None)
    futures = {pool.submit(execute, t): t for t in tasks}
    lost: list[RunTask] = []
    try:
        for fut in as_completed(futures):
            try:
                rec = fut.result()
            except BrokenProcessPool:
                if not final:
                    lost.append(futures[fut])
                    continue
                rec = record(futures[fut], "failed", "worker-lost", 1, "the local worker process died twice while "
                             "the pool held this run (killed, or out of memory)", attempts=2)
            done(rec)
    except BaseException:
        stop.set()  # runs already handed to the pool's queue return at once
        for fut in futures:
            fut.cancel()
        for child in multiprocessing.active_children():  # interrupt the runs under way; idle workers ignore it
            try:
                os.kill(child.pid, signal.SIGINT)
            except OSError:
                pass
        pool.shutdown(wait=True, cancel_futures=True)
        raise
    pool.shutdown(wait=True)
    order = {t.name: i for i, t in enumerate(tasks)}
    return sorted(lost, key=lambda t: order[t.name])


@contextmanager
def _dask_client(address: str, workers: int):
    import dask
    from distributed import Client, LocalCluster

    # a lost worker's task runs once more, then fails (KilledWorker); the workers' profiler is off (nobody reads
    # it, the runs pay for it); workers keep glibc's malloc trim threshold (the nanny's small one costs CPU)
    with dask.config.set({"distributed.scheduler.allowed-failures": DASK_RETRIES,
                          "distributed.worker.profile.enabled": False,
                          "distributed.nanny.pre-spawn-environ.MALLOC_TRIM_THRESHOLD_": None}):
        if address == "local":
            with LocalCluster(n_workers=workers, threads_per_worker=1, processes=True, dashboard_address=None,
                              silence_logs=logging.ERROR) as cluster, Client(cluster) as client:
                yield client
            return
        try:
            client = Client(address, timeout=10)
        except (OSError, TimeoutError) as err:
            raise InputError(f"--dask {address}: cannot reach the Dask scheduler ({err})") from err
    with client:
        yield client


def _run_dask(client, tasks: list[RunTask], done: Done) -> None:
    from distributed import as_completed as dask_completed
    from distributed.scheduler import KilledWorker

    batch_id = uuid.uuid4().hex[:8]
    futures = {client.submit(execute, t, key=f"lio-batch-{batch_id}-{t.name}", pure=False, retries=DASK_RETRIES): t
               for t in tasks}
    try:
        for fut in dask_completed(list(futures)):
            task = futures[fut]
            try:
                rec = fut.result()
            except KilledWorker:
                rec = record(task, "failed", "worker-lost", 1, f"the Dask worker running it was lost "
                             f"{DASK_RETRIES + 1} times (killed, or out of memory)", attempts=DASK_RETRIES + 1)
            except Exception as err:  # e.g. the task could not be unpickled on the worker
                rec = record(task, "failed", "internal", 1, f"Dask: {type(err).__name__}: {err}".splitlines()[0],
                             attempts=DASK_RETRIES + 1)
            done(rec)
    except BaseException:
        client.cancel(list(futures))
        raise


__all__ = ["DASK_INSTALL", "DASK_RETRIES", "Executor", "choose_executor", "dask_available"]
