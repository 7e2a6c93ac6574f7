"""``lio batch --dask`` against a real Dask scheduler and two real workers (separate processes on 127.0.0.1,
free ports, bounded waits, always torn down): results equal the serial single-command runs, and a worker
killed mid-batch has its run retried once on the other worker, as the summary records."""

from __future__ import annotations

import contextlib
import io
import json
import os
import signal
import socket
import subprocess
import sys
import time
from pathlib import Path

import distributed  # the dask extra; in the test extra, so a missing Dask fails here instead of skipping

import lio_cli
from lio_cli.cli.app import main

ROOT = str(Path(lio_cli.__file__).parents[1])  # this checkout: scheduler, workers and the batch import it
START_TIMEOUT_S = 90
LIO = [sys.executable, "-c", "import sys; from lio_cli.cli.app import entry; sys.argv[0] = 'lio'; entry()"]


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


@contextlib.contextmanager
def dask_cluster(logdir: Path, workers: int = 2):
    """``dask scheduler`` and ``workers`` x ``dask worker --no-nanny`` (one thread each); yields (address, worker
    processes). The scheduler retries a lost worker's task once (allowed-failures 1), as lio asks of a cluster."""
    address = f"tcp://127.0.0.1:{free_port()}"
    env = {**os.environ, "PYTHONPATH": ROOT, "DASK_DISTRIBUTED__SCHEDULER__ALLOWED_FAILURES": "1"}
    procs: list[subprocess.Popen] = []
    logdir.mkdir(parents=True, exist_ok=True)

    def start(name: str, argv: list[str]) -> subprocess.Popen:
        p = subprocess.Popen([sys.executable, "-m", *argv], env=env, stdout=subprocess.DEVNULL,
                             stderr=(logdir / f"{name}.log").open("w"))
        procs.append(p)
        return p

    try:
        start("scheduler", ["distributed.cli.dask_scheduler", "--host", "127.0.0.1", "--port",
                            address.rsplit(":", 1)[1], "--no-dashboard"])
        ws = [start(f"worker{i}", ["distributed.cli.dask_worker", address, "--nthreads", "1", "--no-nanny",
                                   "--host", "127.0.0.1", "--name", f"w{i}", "--no-dashboard",
                                   "--death-timeout", str(START_TIMEOUT_S)]) for i in range(workers)]
        with distributed.Client(address, timeout=START_TIMEOUT_S) as client:
            client.wait_for_workers(workers, timeout=START_TIMEOUT_S)
        yield address, ws
    finally:
        for p in reversed(procs):
            if p.poll() is None:
                p.terminate()
        for p in procs:
            try:
                p.wait(timeout=15)
            except subprocess.TimeoutExpired:
                p.kill()
                p.wait()


def assert_as_single_command(sim, run: Path, name: str) -> None:
    ref = sim.ref_files(name)
    assert (run / "odom.tum").read_bytes() == ref["tum"].read_bytes()
    assert (run / "odom.config.yaml").read_bytes() == ref["config"].read_bytes()
    got = json.loads((run / "odom.metrics.json").read_text())
    want = json.loads(ref["metrics"].read_text())
    assert got["scans"] == want["scans"] and got["topics"] == want["topics"]
    assert got["accuracy"]["matches"] == want["accuracy"]["matches"]


def test_dask_cluster_results_equal_serial_single_command_runs(sim, tmp_path):
    out = tmp_path / "out"
    with dask_cluster(tmp_path / "dask") as (address, workers):
        stdout = io.StringIO()
        with contextlib.redirect_stdout(stdout):
            rc = main(["batch", "odom", *map(str, sim.logs.values()), "--gt", "/ground_truth", "-O", str(out),
                       "--dask", address, "-q", "--json"])
        pids = {str(w.pid) for w in workers}
    assert rc == 0
    summary = json.loads(stdout.getvalue())
    assert summary["executor"] == f"the Dask scheduler at {address}"
    assert summary["counts"]["ok"] == 3 and summary["exit_code"] == 0
    for r in summary["runs"]:
        assert (r["status"], r["attempts"]) == ("ok", 1)
        assert r["worker"].rsplit(":", 1)[1] in pids  # run by a worker process, not by the batch
        assert_as_single_command(sim, out / r["name"], r["name"])
    assert sorted(p.name for p in out.iterdir()) == sorted([*sim.logs, "summary.csv", "summary.json"])


def test_killed_worker_task_is_retried_once_on_the_other_worker(sim, tmp_path):
    out = tmp_path / "out"
    with dask_cluster(tmp_path / "dask") as (address, workers):
        pids = {w.pid: w for w in workers}
        batch = subprocess.Popen([*LIO, "batch", "odom", *map(str, sim.logs.values()), "--gt", "/ground_truth",
                                  "-O", str(out), "--dask", address, "-q"],
                                 env={**os.environ, "PYTHONPATH": ROOT}, stdout=subprocess.PIPE,
                                 stderr=subprocess.PIPE, text=True)
        try:
            victim = run = None
            deadline = time.monotonic() + START_TIMEOUT_S
            while victim is None and batch.poll() is None and time.monotonic() < deadline:
                for attempt in out.glob(".*.partial-*/attempt.json"):  # a run a worker is writing now
                    try:
                        pid = json.loads(attempt.read_text())["pid"]
                    except (OSError, ValueError):
                        continue  # being written
                    if pid in pids:
                        os.kill(pid, signal.SIGKILL)
                        victim, run = pid, attempt.parent.name[1:].split(".partial-")[0]
                        break
                time.sleep(0.01)
            assert victim is not None, "no worker was seen running a run"
            _, err = batch.communicate(timeout=300)
        finally:
            if batch.poll() is None:
                batch.kill()
                batch.wait()
        survivor = next(str(p) for p in pids if p != victim)
    assert batch.returncode == 0, err
    summary = json.loads((out / "summary.json").read_text())
    runs = {r["name"]: r for r in summary["runs"]}
    assert summary["counts"]["ok"] == 3
    assert runs[run]["attempts"] == 2  # the lost attempt, then the retry
    assert runs[run]["worker"].rsplit(":", 1)[1] == survivor
    assert all(r["attempts"] == 1 for n, r in runs.items() if n != run)
    for name in sim.logs:
        assert_as_single_command(sim, out / name, name)
    assert not [p for p in out.iterdir() if p.name.startswith(".")]  # the lost attempt's partial folder is gone


def test_dask_local_cluster(sim, tmp_path):
    out = tmp_path / "out"
    rc = main(["batch", "odom", str(sim.logs["walk_a"]), "--gt", "/ground_truth", "-O", str(out),
               "--dask", "local", "--workers", "1", "-q"])
    assert rc == 0
    summary = json.loads((out / "summary.json").read_text())
    assert summary["executor"] == "a local Dask cluster of 1 worker"
    assert_as_single_command(sim, out / "walk_a", "walk_a")


def test_local_dask_workers_do_not_get_dasks_malloc_trim_threshold(monkeypatch):
    """Dask's nanny sets MALLOC_TRIM_THRESHOLD_=65536 in its workers, which made each odometry run take 1.7x the
    CPU; ``--dask local`` workers keep the environment's (here: none)."""
    from lio_cli.batch.executors import _dask_client

    monkeypatch.delenv("MALLOC_TRIM_THRESHOLD_", raising=False)
    with _dask_client("local", 1) as client:
        seen = client.submit(os.environ.get, "MALLOC_TRIM_THRESHOLD_", pure=False).result(timeout=60)
        threads = client.submit(os.environ.get, "OMP_NUM_THREADS", pure=False).result(timeout=60)
    assert seen is None
    assert threads == "1"  # the rest of Dask's worker environment is kept
