"""A batch from start to end: plan (every run's job resolved and the output root checked before any work),
run (on an executor, each record reported as it comes back), summarise (written even when interrupted)."""

from __future__ import annotations

import os
import shutil
import time
from collections.abc import Callable
from pathlib import Path

from ..errors import ConfigError, InputError
from ..io.logs.detect import input_paths
from ..io.files.atomic import check_writable
from .commands import resolve_config
from .executors import Executor
from .lock import batch_lock
from .manifest import RunSpec
from .runs import HASH_FILE, RunTask, finished_since, partial_folders, record
from .summary import Summary, write_summary

SUMMARY_FILES = ("summary.json", "summary.csv")


def plan_batch(specs: list[RunSpec], root: Path | None, resume: bool, force: bool) -> list[RunTask]:
    """One task per run, configurations resolved (a bad option is a ``ConfigError``, exit 2), and the output
    root checked: it may be written, is no input, and holds no earlier batch unless --resume or --force."""
    if root is None:
        raise ConfigError("no output root: give -O DIR (or output: in the manifest)")
    root = Path(os.path.abspath(Path(root).expanduser()))
    tasks = [RunTask(s.name, s.command, s.log, s.group, s.gt, resolve_config(s), root, resume) for s in specs]
    if root.exists() and not root.is_dir():
        raise InputError(f"{root}: exists and is not a folder")
    inputs = [p for s in specs if s.log.exists() for p in input_paths(s.log)]  # logs this machine sees
    check_writable(root if not root.exists() else root / SUMMARY_FILES[0], True, inputs)
    if root.exists():  # no run folder may be (or hold, or lie in) a log: a run replaces its folder
        for t in tasks:
            check_writable(root / t.name, True, inputs, replaceable=_run_folder)
    if root.exists() and not (resume or force):
        earlier = [root / n for n in SUMMARY_FILES] + [root / t.name for t in tasks]
        found = [p for p in earlier if p.exists()]
        if found:
            raise InputError(f"{found[0]}: already exists; pass --resume to skip the runs finished by the same "
                             "job, or --force to redo them")
    return tasks


def run_batch(tasks: list[RunTask], executor: Executor, done: Callable[[dict], None] | None = None) -> Summary:
    """Run every task; write the summary (also when interrupted: unfinished runs are 'not-run')."""
    root = tasks[0].root if tasks else None
    if root is None:
        raise ConfigError("the batch has no runs")
    created = not root.exists()
    root.mkdir(exist_ok=True)
    try:
        with batch_lock(root):  # one batch per root: a second one would take our partial folders for leftovers
            return _run_locked(tasks, executor, done, root)
    except BaseException:
        if created and not any(root.iterdir()):  # refused, or an unreachable scheduler: nothing left behind
            root.rmdir()
        raise


def _run_locked(tasks: list[RunTask], executor: Executor, done: Callable[[dict], None] | None, root: Path) -> Summary:
    _remove_partial_folders(root)  # from a batch killed before it could clean up
    with executor.open() as run:  # connected first: an unreachable scheduler leaves nothing behind
        t0, started = time.perf_counter(), time.time()
        records: dict[str, dict] = {}

        def finished(rec: dict) -> None:
            records[rec["name"]] = rec
            if done is not None:
                done(rec)

        stopped: BaseException | None = None
        try:
            run(tasks, finished)
        except Exception:
            raise
        except BaseException as err:  # Ctrl-C, SIGTERM: the executor stops its workers first
            stopped = err
    if stopped is not None:  # then what they left half-written goes; the summary says what finished and what not
        _remove_partial_folders(root)
        for task in tasks:
            if records.get(task.name, {}).get("status") in (None, "not-run"):
                late = finished_since(task, started)
                if late is not None:
                    records[task.name] = late
        write_summary(_summary(tasks, records, executor, time.perf_counter() - t0, interrupted=True))
        raise stopped
    _count_lost_attempts(root, records)
    summary = _summary(tasks, records, executor, time.perf_counter() - t0)
    write_summary(summary)
    return summary


def _remove_partial_folders(root: Path) -> None:
    for leftovers in partial_folders(root).values():
        for p in leftovers:
            shutil.rmtree(p, ignore_errors=True)


def _count_lost_attempts(root: Path, records: dict[str, dict]) -> None:
    """A partial folder left after the batch is an attempt whose worker died; count it on its run and remove it."""
    for name, leftovers in partial_folders(root).items():
        if name in records and records[name]["status"] == "ok":
            records[name]["attempts"] += len(leftovers)
        for p in leftovers:
            shutil.rmtree(p, ignore_errors=True)


def _summary(tasks: list[RunTask], records: dict[str, dict], executor: Executor, wall_s: float,
             interrupted: bool = False) -> Summary:
    runs = [records.get(t.name) or record(t, "not-run", "interrupted", 130, "the batch was interrupted before this "
                                          "run finished", attempts=0) for t in tasks]
    return Summary(tasks[0].root, executor.describe(), runs, wall_s, interrupted)


__all__ = ["SUMMARY_FILES", "plan_batch", "run_batch"]


def _run_folder(folder: Path) -> bool:
    """A folder a run may replace: one a finished run wrote (its job hash inside), or an empty one."""
    return (folder / HASH_FILE).is_file() or not any(folder.iterdir())
