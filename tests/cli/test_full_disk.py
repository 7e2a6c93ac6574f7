"""Outputs on a full device (issue 32), on a real 600 kB tmpfs: exit 1 with one line "no space left on device:
PATH", nothing half-written, inputs untouched; a batch records the run as failed and still writes its summary.
Needs the right to mount a tmpfs (root in a container); skipped, saying so, where that is refused."""

from __future__ import annotations

import json
import subprocess

import pytest

from lio_cli.cli.app import main
from lio_cli.simulation.run import simulate


@pytest.fixture(scope="module")
def log(tmp_path_factory):
    root = tmp_path_factory.mktemp("full_disk_log")
    return simulate("handheld", root / "walk.bag", "ros1", duration_s=3.0, seed=4).log_path


@pytest.fixture()
def full(tmp_path):
    """A 600 kB tmpfs, unmounted afterwards."""
    disk = tmp_path / "disk"
    disk.mkdir()
    res = subprocess.run(["mount", "-t", "tmpfs", "-o", "size=600k", "tmpfs", str(disk)], capture_output=True, text=True)
    if res.returncode != 0:
        pytest.skip(f"cannot mount a 600 kB tmpfs here ({res.stderr.strip() or 'mount refused'}): the full-disk "
                    "paths are covered by tests/io/files/test_atomic.py's injected ENOSPC")
    try:
        yield disk
    finally:
        subprocess.run(["umount", "-l", str(disk)], check=False)


@pytest.mark.parametrize("argv, out", [
    (["deskew", "{log}", "{disk}/out.bag"], "out.bag"),
    (["deskew", "{log}", "{disk}/out.mcap"], "out.mcap"),
    (["deskew", "{log}", "{disk}/out_ros2", "--format", "ros2"], "out_ros2"),
    (["fuse", "{log}", "-o", "{disk}/fused.tum", "--rate", "5000"], "fused.tum"),
])
def test_a_full_device_is_one_line_and_leaves_nothing(log, full, capsys, argv, out):
    before = log.read_bytes()
    assert main([a.format(log=log, disk=full) for a in argv]) == 1
    err = capsys.readouterr().err
    assert err.splitlines()[-1] == f"lio: error: no space left on device: {full / out}"
    assert "Traceback" not in err and "internal error" not in err
    assert list(full.iterdir()) == []
    assert log.read_bytes() == before


def test_a_batch_records_the_full_device_as_a_failed_run_and_writes_its_summary(log, full, capsys):
    assert main(["batch", "deskew", str(log), "-O", str(full / "b"), "--jobs", "1", "-q"]) == 1
    assert capsys.readouterr().err == (f"lio: warning: walk: processing: no space left on device: "
                                       f"{full / 'b' / 'walk' / 'deskew.bag'}\n")
    summary = json.loads((full / "b" / "summary.json").read_text())
    run = summary["runs"][0]
    assert (run["status"], run["exit_class"], run["exit_code"]) == ("failed", "processing", 1)
    assert sorted(p.name for p in (full / "b").iterdir()) == ["summary.csv", "summary.json"]
