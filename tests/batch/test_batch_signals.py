"""``lio batch`` under signals and concurrency (issue 32): one batch per output root (a lock held for the run),
Ctrl-C and SIGTERM to the whole process group at start-up and while runs are under way (local processes and a
local Dask cluster) end it with exit 130/143 and one line, no partial folder, and a summary equal to the
folders. Every wait is bounded: a regression fails, it does not hang the suite."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

import lio_cli
from lio_cli.batch.lock import LOCK_FILE, batch_lock
from lio_cli.cli.app import main

LIO = [sys.executable, "-m", "lio_cli"]  # the console script's start-up (cli.launch) included
WAIT_S = 120  # any wait of these tests; a batch that does not end by then has hung
EXIT_S = 30  # from the signal to the batch's exit


def _env() -> dict:
    return {**os.environ, "PYTHONPATH": str(Path(lio_cli.__file__).parents[1])}


def _start(argv: list[str], cwd: Path) -> subprocess.Popen:
    return subprocess.Popen([*LIO, *argv], cwd=cwd, env=_env(), stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                            text=True, start_new_session=True)  # its own group: the signal goes to every worker


def _signal_group(proc: subprocess.Popen, sig: int) -> tuple[int, str]:
    """Send ``sig`` to the batch's process group; (exit code, stderr), or fail when it does not end in time."""
    try:
        os.killpg(proc.pid, sig)
    except ProcessLookupError:
        pass
    try:
        _, err = proc.communicate(timeout=EXIT_S)
    except subprocess.TimeoutExpired:
        os.killpg(proc.pid, signal.SIGKILL)
        proc.communicate()
        pytest.fail(f"the batch did not end within {EXIT_S} s of the signal")
    return proc.returncode, err


def _wait_for_a_run_under_way(proc: subprocess.Popen, out: Path) -> None:
    deadline = time.monotonic() + WAIT_S
    while not list(out.glob(".*.partial-*/attempt.json")):
        if proc.poll() is not None or time.monotonic() > deadline:
            os.killpg(proc.pid, signal.SIGKILL)
            pytest.fail(f"no run was seen under way (exit {proc.poll()}): {proc.communicate()[1]}")
        time.sleep(0.02)


def _assert_summary_equals_folders(out: Path) -> dict:
    summary = json.loads((out / "summary.json").read_text())
    assert summary["interrupted"] and summary["exit_code"] == 1
    done = sorted(r["name"] for r in summary["runs"] if r["status"] == "ok")
    assert sorted(p.name for p in out.iterdir() if p.is_dir()) == done  # no partial folder, no unreported run
    assert not [p for p in out.iterdir() if p.name.startswith(".")]  # nor the lock
    return summary


def test_a_second_batch_on_the_same_root_is_refused_at_once(sim, tmp_path, capsys):
    out = tmp_path / "out"
    out.mkdir()
    with batch_lock(out):
        assert (out / LOCK_FILE).read_text() == f"{os.getpid()}\n"
        assert main(["batch", "odom", str(sim.logs["walk_a"]), "-O", str(out), "--resume", "-q"]) == 2
    assert capsys.readouterr().err == (f"lio: error: {out}: is in use by pid {os.getpid()} (another lio batch "
                                       "writing there); wait for it to end, or choose another output root\n")
    assert sorted(p.name for p in out.iterdir()) == []  # nothing written, the holder's lock gone with it


def test_a_dead_batchs_lock_is_taken_over(sim, tmp_path):
    out = tmp_path / "out"
    out.mkdir()
    (out / LOCK_FILE).write_text("999999999\n")  # its process is gone, so is its flock
    assert main(["batch", "odom", str(sim.logs["office"]), "-O", str(out), "--jobs", "1", "-q"]) == 0
    assert sorted(p.name for p in out.iterdir()) == ["office", "summary.csv", "summary.json"]


def _lock_text(out):
    try:
        return (out / LOCK_FILE).read_text()
    except OSError:
        return ""


def test_two_batches_started_together_one_runs_the_other_is_refused(sim, tmp_path):
    argv = ["batch", "odom", str(sim.logs["walk_a"]), str(sim.logs["office"]), "-O", "out", "--resume", "--jobs", "1",
            "-q"]
    first = _start(argv, tmp_path)
    try:
        deadline = time.monotonic() + WAIT_S
        # the pid in the file: the first has locked it (a bare file may be a moment before its flock and write)
        while _lock_text(tmp_path / "out") != f"{first.pid}\n" and first.poll() is None and time.monotonic() < deadline:
            time.sleep(0.01)
        os.killpg(first.pid, signal.SIGSTOP)  # the first holds the lock, mid-batch, for as long as the second takes
        try:
            second = subprocess.run([*LIO, *argv], cwd=tmp_path, env=_env(), capture_output=True, text=True,
                                    timeout=WAIT_S)
        finally:
            os.killpg(first.pid, signal.SIGCONT)
        _, err = first.communicate(timeout=WAIT_S)
    finally:
        if first.poll() is None:
            os.killpg(first.pid, signal.SIGKILL)
    assert first.returncode == 0, err
    assert second.returncode == 2
    assert second.stderr.startswith(f"lio: error: {tmp_path / 'out'}: is in use by pid {first.pid} ")
    summary = json.loads((tmp_path / "out" / "summary.json").read_text())
    assert [r["status"] for r in summary["runs"]] == ["ok", "ok"]
    assert sorted(p.name for p in (tmp_path / "out").iterdir()) == ["office", "summary.csv", "summary.json", "walk_a"]


@pytest.mark.parametrize("sig, code, word", [(signal.SIGINT, 130, "interrupted"), (signal.SIGTERM, 143, "terminated")])
def test_a_signal_during_start_up_is_one_line(sim, tmp_path, sig, code, word):
    """0.6 s in: the interpreter still imports lio's modules (a traceback from inside an import, before)."""
    proc = _start(["batch", "deskew", *map(str, sim.logs.values()), "-O", "out", "--jobs", "2", "-q"], tmp_path)
    time.sleep(0.6)
    rc, err = _signal_group(proc, sig)
    assert (rc, err) == (code, f"lio: {word}; nothing half-written was left behind\n")


@pytest.mark.parametrize("sig, code, word", [(signal.SIGINT, 130, "interrupted"), (signal.SIGTERM, 143, "terminated")])
@pytest.mark.parametrize("where", [["--jobs", "2"], ["--dask", "local", "--workers", "2"]], ids=["pool", "dask"])
def test_a_signal_to_the_group_while_runs_are_under_way(sim, tmp_path, sig, code, word, where):
    """The pool printed 'interrupted' and hung (its workers died of the signal mid-start-up, or were still
    running), SIGTERM left partial folders and exited -15; Dask printed tracebacks (AssertionError: Status.init)."""
    if "--dask" in where:
        pytest.importorskip("distributed")
    proc = _start(["batch", "deskew", *map(str, sim.logs.values()), "-O", "out", "-q", *where], tmp_path)
    _wait_for_a_run_under_way(proc, tmp_path / "out")
    rc, err = _signal_group(proc, sig)
    assert (rc, err) == (code, f"lio: {word}; nothing half-written was left behind\n")
    summary = _assert_summary_equals_folders(tmp_path / "out")
    assert {r["status"] for r in summary["runs"]} <= {"ok", "not-run"}


def test_an_interrupt_a_callback_swallowed_interrupts_the_run_at_its_next_step(monkeypatch, capsys):
    """A worker's interrupt raised inside an import's lock callback was printed as 'Exception ignored in: ...'
    under the batch's one line, and the run went on."""
    import weakref

    from lio_cli.batch import runs

    monkeypatch.setattr(runs, "_in_pool", True)
    monkeypatch.setattr(sys, "unraisablehook", runs._unraisable)
    handlers = signal.getsignal(signal.SIGINT), signal.getsignal(signal.SIGTERM), signal.getsignal(signal.SIGALRM)

    class Held:
        pass

    def swallowed(_ref):
        raise KeyboardInterrupt  # where Python can only hand it to the unraisable hook

    t0 = time.perf_counter()
    try:
        with pytest.raises(KeyboardInterrupt):
            with runs._interruptible():
                held = Held()
                ref = weakref.ref(held, swallowed)  # noqa: F841 - its callback runs when held goes
                del held
                while time.perf_counter() - t0 < 5:  # the run's next steps: the interrupt comes among them
                    pass
    finally:
        signal.setitimer(signal.ITIMER_REAL, 0)
        signal.signal(signal.SIGINT, handlers[0])
        signal.signal(signal.SIGTERM, handlers[1])
        signal.signal(signal.SIGALRM, handlers[2])
    assert capsys.readouterr().err == ""
