"""The C heap trimmed when an odometry run ends: once per run, a no-op without glibc, memory really handed back,
and the trajectory unchanged by it."""

from __future__ import annotations

import ctypes
import os
import sys

import numpy as np
import pytest

import lio_cli.heap as heap
import lio_cli.jobs.odom.job as odom_job
from lio_cli.cli.app import main
from lio_cli.config.odom import OdomConfig
from lio_cli.simulation.run import simulate


@pytest.fixture
def uncached():
    heap.glibc_trim.cache_clear()
    yield
    heap.glibc_trim.cache_clear()


def test_without_linux_there_is_nothing_to_trim(monkeypatch, uncached):
    monkeypatch.setattr(sys, "platform", "darwin")
    assert heap.glibc_trim() is None and heap.trim_heap() is False


def test_a_c_library_other_than_glibc_is_left_alone(monkeypatch, uncached):
    class Musl:  # has malloc but neither gnu_get_libc_version nor malloc_trim
        malloc = object()

    monkeypatch.setattr(sys, "platform", "linux")
    monkeypatch.setattr(ctypes, "CDLL", lambda name: Musl())
    assert heap.glibc_trim() is None and heap.trim_heap() is False


def _rss_mb() -> float:
    with open("/proc/self/statm") as f:
        return int(f.read().split()[1]) * os.sysconf("SC_PAGE_SIZE") / 2**20


@pytest.mark.skipif(heap.glibc_trim() is None, reason="glibc's malloc_trim is not available here")
def test_free_holes_inside_the_heap_leave_the_resident_set():
    """1000 blocks of 32 kB (below glibc's mmap threshold, so inside the heap), three of every four freed: 23 MB
    of holes between live blocks, which free() cannot give back and malloc_trim does."""
    blocks = [np.full(4096, float(i)) for i in range(1000)]
    kept = blocks[::4]
    del blocks
    before = _rss_mb()
    assert heap.glibc_trim()() == 1
    released = before - _rss_mb()
    assert released > 15.0, (before, released)
    assert all(float(b[0]) == 4 * i and float(b[-1]) == 4 * i for i, b in enumerate(kept))  # live blocks untouched


def test_an_odometry_run_trims_the_heap_once_at_its_end_and_its_trajectory_is_unchanged(tmp_path, monkeypatch):
    res = simulate("handheld", tmp_path / "walk.bag", "ros1", duration_s=3.0, seed=2, columns=360)
    monkeypatch.setattr(odom_job, "trim_heap", lambda: False)
    assert main(["odom", str(res.log_path), "-o", str(tmp_path / "plain.tum"), "-q"]) == 0
    written = []  # whether the trajectory was already written at each trim: no, the run's end comes first
    monkeypatch.setattr(odom_job, "trim_heap", lambda: written.append((tmp_path / "trimmed.tum").exists()) or True)
    assert main(["odom", str(res.log_path), "-o", str(tmp_path / "trimmed.tum"), "-q"]) == 0
    assert written == [False]
    assert (tmp_path / "trimmed.tum").read_bytes() == (tmp_path / "plain.tum").read_bytes()


def test_a_failed_odometry_run_trims_the_heap_too(tmp_path, monkeypatch):
    res = simulate("handheld", tmp_path / "walk.bag", "ros1", duration_s=1.0, seed=2, columns=360)
    calls = []
    monkeypatch.setattr(odom_job, "trim_heap", lambda: calls.append(1) or True)

    def lost(self):
        raise odom_job.ProcessingError("lost")

    monkeypatch.setattr(odom_job._OdomRun, "run", lost)
    with pytest.raises(odom_job.ProcessingError, match="lost"):
        odom_job.run_odom(odom_job.OdomJob(res.log_path, OdomConfig()))
    assert calls == [1]
