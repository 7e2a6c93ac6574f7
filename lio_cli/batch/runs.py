"""One run of a batch where it runs (this process, a pool process or a Dask worker): ``execute(task)``.

A ``RunTask`` is plain picklable data (names, absolute paths, the resolved configuration). ``execute`` checks
that this machine sees the log and the output root (logs and results live on storage every worker shares),
computes the job's hash, skips the run when ``--resume`` finds a finished folder of the same job, else runs the
command into a hidden ``.NAME.partial-*`` folder beside the final one and renames it into place: a run folder
is complete or absent. Every failure becomes a record (exit class and one line), never an exception, except
an interruption, which removes the partial folder on its way out.
"""

from __future__ import annotations

import hashlib
import json
import os
import shutil
import signal
import socket
import sys
import threading
import time
import uuid
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from pydantic import BaseModel

from .. import __version__
from ..errors import LioError
from ..buffers import release_idle_buffers
from ..heap import trim_heap
from ..io.files.atomic import replace_path
from .commands import key_metrics, metrics_file, run_command

HASH_FILE = "job.sha256"
PARTIAL = ".partial-"  # a run folder being written: .NAME.partial-UUID
ATTEMPT_FILE = "attempt.json"  # inside a partial folder: which worker writes it

_in_pool = False  # set in local pool processes: Ctrl-C interrupts a run, never an idle worker
_stop = None  # in local pool processes: an Event set when the batch stops; runs still queued do not start


@dataclass(frozen=True)
class RunTask:
    name: str
    command: str
    log: Path
    group: str | None
    gt: str | None
    config: BaseModel  # the command's resolved configuration model
    root: Path  # the output root; the run's folder is root / name
    resume: bool = False


def _log_files(log: Path) -> list[Path]:
    if log.is_dir():
        return sorted(p for p in log.rglob("*") if p.is_file())
    return [log]


def job_description(task: RunTask) -> dict[str, Any]:
    """What the job hash covers: lio's version, the command, the configuration, the ground truth, and the log
    (path and each file's size and modification time as this machine sees them)."""
    files = [[str(p), p.stat().st_size, p.stat().st_mtime_ns] for p in _log_files(task.log)]
    gt_file = Path(task.gt) if task.gt is not None and Path(task.gt).is_file() else None
    return {"lio": __version__, "command": task.command, "log": str(task.log), "log_files": files,
            "gt": task.gt, "gt_file": None if gt_file is None else [gt_file.stat().st_size, gt_file.stat().st_mtime_ns],
            "config": task.config.model_dump(mode="json")}


def job_hash(task: RunTask) -> str:
    text = json.dumps(job_description(task), sort_keys=True, separators=(",", ":"))
    return hashlib.sha256(text.encode()).hexdigest()


def worker_name() -> str:
    return f"{socket.gethostname()}:{os.getpid()}"


def record(task: RunTask, status: str, exit_class: str, exit_code: int, reason: str = "", *, time_s: float = 0.0,
           metrics: dict | None = None, worker: str | None = None, attempts: int = 1) -> dict[str, Any]:
    """One row of the summary."""
    return {"name": task.name, "group": task.group, "command": task.command, "log": str(task.log),
            "status": status, "exit_class": exit_class, "exit_code": exit_code, "reason": reason,
            "time_s": round(time_s, 3), "attempts": attempts, "worker": worker,
            "folder": str(task.root / task.name) if status in ("ok", "skipped") else None,
            "metrics": metrics or key_metrics_empty()}


def key_metrics_empty() -> dict[str, Any]:
    from .commands import KEY_METRICS

    return dict.fromkeys(KEY_METRICS)


def _one_line(err: BaseException) -> str:
    text = str(err).strip() or type(err).__name__
    return text.splitlines()[0]


def pool_initializer(stop=None) -> None:
    """In a local pool process: Ctrl-C and SIGTERM do nothing while idle (the batch decides: it interrupts the
    runs under way itself); ``execute`` lets them interrupt a run; once ``stop`` is set no queued run starts. The
    process starts with both blocked (``executors.signals_blocked``): one sent meanwhile is dropped here."""
    global _in_pool, _stop
    _in_pool, _stop = True, stop
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    signal.signal(signal.SIGTERM, signal.SIG_IGN)
    sys.unraisablehook = _unraisable
    signal.pthread_sigmask(signal.SIG_UNBLOCK, {signal.SIGINT, signal.SIGTERM})


def _ignore(signum, frame) -> None:  # noqa: ARG001 - signal handler signature
    """Ignore a signal in Python (SIG_IGN set while one is already caught makes Python raise OSError)."""


def _raise_interrupt(signum, frame) -> None:  # noqa: ARG001 - signal handler signature
    """Interrupt the run once: a second signal (the group's, then the batch's own) would break its clean-up."""
    signal.signal(signal.SIGINT, _ignore)
    signal.signal(signal.SIGTERM, _ignore)
    raise KeyboardInterrupt


INTERRUPT_AGAIN_S = 0.01  # a swallowed interrupt comes again this much later, outside the callback


def _unraisable(hook_args) -> None:
    """An interrupt raised where Python can only print it (an import's lock callback, a finaliser) interrupts the
    run at its next step instead of printing 'Exception ignored in: ...' on the batch's terminal."""
    if isinstance(hook_args.exc_value, KeyboardInterrupt):
        signal.signal(signal.SIGALRM, _raise_interrupt)  # raised from the hook it would be swallowed again
        signal.setitimer(signal.ITIMER_REAL, INTERRUPT_AGAIN_S)
        return
    sys.__unraisablehook__(hook_args)


@contextmanager
def _interruptible():
    if not (_in_pool and threading.current_thread() is threading.main_thread()):
        yield
        return
    signal.signal(signal.SIGINT, _raise_interrupt)
    signal.signal(signal.SIGTERM, _raise_interrupt)
    try:
        yield
    finally:
        signal.signal(signal.SIGINT, _ignore)
        signal.signal(signal.SIGTERM, _ignore)


def execute(task: RunTask) -> dict[str, Any]:
    """Run ``task`` here; return its summary record (see the module docstring)."""
    t0 = time.perf_counter()
    here = worker_name()
    if _stop is not None and _stop.is_set():
        return record(task, "not-run", "interrupted", 130, "the batch was interrupted before this run started",
                      attempts=0)
    with _interruptible():
        try:
            return _execute(task, here, t0)
        except LioError as err:
            cls = "input" if err.exit_code == 2 else "processing"
            return record(task, "failed", cls, err.exit_code, _one_line(err), time_s=time.perf_counter() - t0,
                          worker=here)
        except Exception as err:  # a bug: recorded, the batch goes on
            return record(task, "failed", "internal", 1, f"internal error: {type(err).__name__}: {_one_line(err)}",
                          time_s=time.perf_counter() - t0, worker=here)
        finally:
            release_idle_buffers()  # the next log's scans may be of other sizes
            trim_heap()  # the run's free heap pages back before this worker's next run


def _execute(task: RunTask, here: str, t0: float) -> dict[str, Any]:
    host = socket.gethostname()
    if not task.log.exists():
        raise _not_visible(f"{task.log}: no such file or folder on {host}")
    if not task.root.is_dir():
        raise _not_visible(f"{task.root}: output root not visible on {host}")
    digest = job_hash(task)
    final = task.root / task.name
    if task.resume and _finished(final) == digest:
        try:
            metrics = key_metrics(task.command, json.loads((final / metrics_file(task.command)).read_text()))
        except (OSError, ValueError, KeyError, TypeError):
            metrics = None  # an unreadable folder is run again
        if metrics is not None:
            return record(task, "skipped", "ok", 0, "finished earlier by the same job",
                          time_s=time.perf_counter() - t0, metrics=metrics, worker=here, attempts=0)
    partial = task.root / f".{task.name}{PARTIAL}{uuid.uuid4().hex[:12]}"
    partial.mkdir()
    try:
        (partial / ATTEMPT_FILE).write_text(json.dumps({"worker": here, "host": host, "pid": os.getpid()}) + "\n")
        try:
            metrics = run_command(task.command, task.log, task.config, task.gt, partial)
        except LioError as err:  # its line names the run's folder, not the hidden one it was written in
            raise type(err)(str(err).replace(str(partial), str(final))) from err
        (partial / ATTEMPT_FILE).unlink()
        (partial / HASH_FILE).write_text(digest + "\n")
        replace_path(partial, final)
    except BaseException:
        shutil.rmtree(partial, ignore_errors=True)
        raise
    return record(task, "ok", "ok", 0, "", time_s=time.perf_counter() - t0,
                  metrics=key_metrics(task.command, metrics), worker=here)


def finished_since(task: RunTask, since: float) -> dict[str, Any] | None:
    """The record of a run whose folder was completed at or after ``since`` (epoch s) when no worker reported
    it (the batch stopped in between); None if there is no such folder."""
    folder = task.root / task.name
    try:
        if (folder / HASH_FILE).stat().st_mtime < since:
            return None
        metrics = json.loads((folder / metrics_file(task.command)).read_text())
    except (OSError, ValueError):
        return None
    return record(task, "ok", "ok", 0, "finished as the batch was interrupted",
                  metrics=key_metrics(task.command, metrics))


def _not_visible(what: str) -> LioError:
    from ..errors import InputError

    return InputError(f"{what} (lio batch reads logs and writes results by path: they must be on storage "
                      "every worker shares)")


def _finished(folder: Path) -> str | None:
    """The job hash of a finished run folder, or None."""
    try:
        return (folder / HASH_FILE).read_text().strip()
    except OSError:
        return None


def running_pids(root: Path) -> set[int]:
    """Process ids of this host's workers writing a partial folder in ``root`` now (their attempt files)."""
    pids, host = set(), socket.gethostname()
    for leftovers in partial_folders(root).values():
        for p in leftovers:
            try:
                attempt = json.loads((p / ATTEMPT_FILE).read_text())
            except (OSError, ValueError):
                continue
            if isinstance(attempt, dict) and attempt.get("host") == host and isinstance(attempt.get("pid"), int):
                pids.add(attempt["pid"])
    return pids


def partial_folders(root: Path) -> dict[str, list[Path]]:
    """Partial run folders in ``root`` by run name (left by a worker that died, or by a killed batch)."""
    out: dict[str, list[Path]] = {}
    for p in root.iterdir() if root.is_dir() else ():
        if p.name.startswith(".") and PARTIAL in p.name and p.is_dir():
            out.setdefault(p.name[1:p.name.index(PARTIAL)], []).append(p)
    return out


__all__ = ["ATTEMPT_FILE", "HASH_FILE", "RunTask", "execute", "finished_since", "job_description", "job_hash",
           "partial_folders", "pool_initializer", "record", "running_pids"]
