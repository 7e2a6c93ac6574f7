"""Where the runs of a batch run: this process, a pool of local processes, or a Dask cluster.

Each executor calls ``execute(task)`` once per task and hands each record to ``done(record)`` as it comes
back (in completion order). A run that fails is a record like any other; a worker that disappears becomes a
``worker-lost`` record. On Ctrl-C the runs still queued are cancelled, the running ones interrupted (local) or
left to finish or die with their worker (Dask; their partial folders never become run folders), and the
interruption propagates.
"""

from __future__ import annotations

import atexit
import contextlib
import logging
import multiprocessing
import os
import signal
import threading
import uuid
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from concurrent.futures import ProcessPoolExecutor, as_completed
from concurrent.futures.process import BrokenProcessPool
from dataclasses import dataclass

from ..cpus import usable_cpus
from ..errors import ConfigError, InputError
from .commands import registration_threads
from .runs import RunTask, execute, pool_initializer, record, running_pids

Done = Callable[[dict], None]
DASK_INSTALL = ("--dask needs the optional Dask dependency: pip install 'lio-cli[dask]' "
                "(or pip install 'dask[distributed]')")
STOP_WAIT_S = 10.0  # an interrupted pool's workers get this long to stop before they are killed
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
    futures: dict = {}
    lost: list[RunTask] = []
    try:
        with signals_blocked(), signals_deferred():  # workers (and the pool's thread that starts more) begin deaf
            for t in tasks:                            # to Ctrl-C and SIGTERM; none stops a worker's start half-way
                futures[pool.submit(execute, t)] = t
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
        _stop_pool(pool, futures, stop, tasks[0].root)
        raise
    pool.shutdown(wait=True)
    order = {t.name: i for i, t in enumerate(tasks)}
    return sorted(lost, key=lambda t: order[t.name])


def _stop_pool(pool: ProcessPoolExecutor, futures: dict, stop, root) -> None:
    """Stop the pool at once: queued runs cancelled, runs under way interrupted (they remove their partial
    folders; idle workers ignore signals), and every worker killed if one is still alive after ``STOP_WAIT_S``,
    so the interpreter's exit never waits. The batch removes what they leave. An idle worker is never killed
    alone: it may hold the lock of the pool's result queue, which its siblings then wait on for ever."""
    stop.set()  # runs already handed to the pool's queue return at once
    for fut in futures:
        fut.cancel()
    children = multiprocessing.active_children()
    running = running_pids(root)
    for child in children:
        if child.pid in running:
            try:
                os.kill(child.pid, signal.SIGINT)
            except OSError:
                pass
    closed = threading.Event()
    threading.Thread(target=lambda: (pool.shutdown(wait=True, cancel_futures=True), closed.set()),
                     daemon=True).start()
    if not closed.wait(STOP_WAIT_S):
        for child in children:
            child.kill()
        closed.wait(STOP_WAIT_S)


@contextmanager
def signals_blocked():
    """SIGINT and SIGTERM held pending in this thread (and in the threads and processes it starts meanwhile,
    which inherit its signal mask): a pool worker unblocks them once it has chosen what they do."""
    held = {signal.SIGINT, signal.SIGTERM}
    before = signal.pthread_sigmask(signal.SIG_BLOCK, held)
    try:
        yield
    finally:
        signal.pthread_sigmask(signal.SIG_SETMASK, before)


@contextmanager
def signals_deferred():
    """SIGINT and SIGTERM arriving in the body take effect after it (Python runs its handlers in the main thread
    whatever the thread masks: one raised while a worker starts leaves it waiting for a setup that never comes)."""
    caught: list[int] = []
    held = (signal.SIGINT, signal.SIGTERM)
    before = {s: signal.signal(s, lambda signum, frame: caught.append(signum)) for s in held}
    try:
        yield
    finally:
        for s, handler in before.items():
            signal.signal(s, handler)
        if caught:
            signal.raise_signal(caught[0])


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
            with _local_cluster(LocalCluster, workers) as cluster, Client(cluster) as client:
                yield client
            return
        try:
            client = Client(address, timeout=10)
        except (OSError, TimeoutError) as err:
            raise InputError(f"--dask {address}: cannot reach the Dask scheduler ({err})") from err
    with client:
        yield client


@contextmanager
def _local_cluster(LocalCluster, workers: int):
    """A Dask cluster of ``workers`` processes on this machine, started with their stderr on /dev/null: a Ctrl-C
    to the process group would have each print a traceback from wherever it was (its errors come back to this
    process with its tasks' results). A cluster interrupted while it starts cannot close cleanly (Dask asserts on
    its state): that is not reported over the interruption."""
    cluster = None
    try:
        with _stderr_to_devnull():  # the worker processes inherit it
            # CRITICAL: a task whose workers died (a signal to the group) is lio's to report, not the scheduler's
            cluster = LocalCluster(n_workers=workers, threads_per_worker=1, processes=True, dashboard_address=None,
                                   silence_logs=logging.CRITICAL)
        yield cluster
    except BaseException:
        _silence_dask()
        from distributed.deploy.spec import close_clusters

        atexit.unregister(close_clusters)  # it would meet the half-started cluster again at exit, and assert
        with _stderr_to_devnull(), contextlib.suppress(Exception):
            close_clusters()  # this one, or one interrupted while it started and never handed back
        raise
    cluster.close(timeout=STOP_WAIT_S)


@contextmanager
def _stderr_to_devnull():
    devnull, saved = os.open(os.devnull, os.O_WRONLY), os.dup(2)
    os.dup2(devnull, 2)
    try:
        yield
    finally:
        os.dup2(saved, 2)
        os.close(saved)
        os.close(devnull)


def _silence_dask() -> None:
    """Dask's own log lines (a nanny's CancelledError while its worker is stopped, a start-up task's error never
    retrieved) say nothing the interrupted batch does not."""
    for name in ("distributed", "asyncio"):
        logging.getLogger(name).setLevel(logging.CRITICAL + 1)


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
        _silence_dask()
        client.cancel(list(futures))
        raise


__all__ = ["DASK_INSTALL", "DASK_RETRIES", "Executor", "choose_executor", "dask_available"]
