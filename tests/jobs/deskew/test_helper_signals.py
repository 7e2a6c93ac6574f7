"""``lio deskew``'s writer process under signals (issue 32): Ctrl-C to the process group, SIGTERM to lio, or lio
killed outright while the helper writes: no temporary output is left, ever. Bounded waits throughout."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

import lio_cli
from lio_cli.cpus import usable_cpus
from lio_cli.simulation.run import simulate

WAIT_S = 120  # any wait here; past it the run has hung
CLEAN_S = 20  # from the signal until the last temporary file is gone

pytestmark = pytest.mark.skipif(usable_cpus() < 2, reason="the writer process runs only with two cores or more")


@pytest.fixture(scope="module")
def walk(tmp_path_factory) -> Path:
    root = tmp_path_factory.mktemp("helper_signals")
    return simulate("handheld", root / "walk.bag", "ros1", duration_s=4.0, seed=3).log_path


def _children(pid: int) -> list[int]:
    try:
        return [int(p) for p in Path(f"/proc/{pid}/task/{pid}/children").read_text().split()]
    except OSError:
        return []


def _temps(folder: Path) -> list[Path]:
    return sorted(folder.glob(".out.bag.*.tmp"))


@pytest.mark.parametrize("how", ["SIGINT to the group", "SIGTERM to lio", "lio killed", "SIGINT and SIGTERM to the helper"])
def test_no_temporary_output_is_left_whatever_stops_the_run(walk, tmp_path, how):
    env = {**os.environ, "PYTHONPATH": str(Path(lio_cli.__file__).parents[1])}
    proc = subprocess.Popen([sys.executable, "-m", "lio_cli", "deskew", str(walk), "out.bag", "-q"], cwd=tmp_path,
                            env=env, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                            start_new_session=True)
    helper = None
    try:
        deadline = time.monotonic() + WAIT_S
        while not (_temps(tmp_path) and _children(proc.pid)):  # the helper is writing the output log
            assert proc.poll() is None and time.monotonic() < deadline, "the helper was never seen writing"
            time.sleep(0.01)
        helper = _children(proc.pid)[0]
        os.kill(helper, signal.SIGSTOP)  # held mid-writing (it writes a short log in a second)
        try:
            if how == "SIGINT to the group":
                os.killpg(proc.pid, signal.SIGINT)
            elif how == "SIGTERM to lio":
                os.kill(proc.pid, signal.SIGTERM)
            elif how == "SIGINT and SIGTERM to the helper":  # the second arrives while it discards its files
                os.kill(helper, signal.SIGINT)
                os.kill(helper, signal.SIGTERM)
            else:
                os.kill(proc.pid, signal.SIGKILL)
            time.sleep(0.3)
        finally:
            os.kill(helper, signal.SIGCONT)
        _, err = proc.communicate(timeout=CLEAN_S)
        deadline = time.monotonic() + CLEAN_S
        while (_temps(tmp_path) or Path(f"/proc/{helper}").exists()) and time.monotonic() < deadline:
            time.sleep(0.05)
    finally:
        for pid in (proc.pid, helper):
            if pid is not None:
                try:
                    os.kill(pid, signal.SIGKILL)
                except ProcessLookupError:
                    pass
    assert _temps(tmp_path) == [] and not (tmp_path / "out.bag").exists()
    assert sorted(p.name for p in tmp_path.iterdir()) == []
    assert not Path(f"/proc/{helper}").exists() or "zombie" in Path(f"/proc/{helper}/status").read_text()
    if how == "SIGINT to the group":
        assert (proc.returncode, err) == (130, "lio: interrupted; nothing half-written was left behind\n")
    elif how == "SIGTERM to lio":
        assert (proc.returncode, err) == (143, "lio: terminated; nothing half-written was left behind\n")
    elif how == "lio killed":
        assert proc.returncode == -signal.SIGKILL
    else:
        assert proc.returncode == 1 and len(err.splitlines()) == 1 and "Traceback" not in err, err
