"""The C heap trimmed every so many scans: on schedule, a no-op without glibc, memory really handed back, and an
odometry run's trajectory unchanged by it."""

from __future__ import annotations

import ctypes
import os
import sys

import numpy as np
import pytest

import lio_cli.heap as heap
import lio_cli.jobs.odom.job as odom_job
from lio_cli.cli.app import main
from lio_cli.simulation.run import simulate


def test_the_heap_is_trimmed_after_every_nth_scan():
    calls = []
    trim = heap.HeapTrim(every=3, trim=lambda: calls.append(len(calls)) or 1)
    at = []
    for scan in range(1, 11):
        trim.scan_done()
        if len(calls) > len(at):
            at.append(scan)
    assert at == [3, 6, 9] and trim.trims == 3 and trim.scans == 10


@pytest.fixture
def uncached():
    heap.glibc_trim.cache_clear()
    yield
    heap.glibc_trim.cache_clear()


def test_without_linux_there_is_nothing_to_trim(monkeypatch, uncached):
    monkeypatch.setattr(sys, "platform", "darwin")
    assert heap.glibc_trim() is None
    trim = heap.HeapTrim(every=1)
    for _ in range(5):
        trim.scan_done()
    assert trim.trim is None and trim.trims == 0 and trim.scans == 5


def test_a_c_library_other_than_glibc_is_left_alone(monkeypatch, uncached):
    class Musl:  # has malloc but neither gnu_get_libc_version nor malloc_trim
        malloc = object()

    monkeypatch.setattr(sys, "platform", "linux")
    monkeypatch.setattr(ctypes, "CDLL", lambda name: Musl())
    assert heap.glibc_trim() is None


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


def test_trimming_after_every_scan_leaves_the_trajectory_byte_for_byte(tmp_path, monkeypatch):
    res = simulate("handheld", tmp_path / "walk.bag", "ros1", duration_s=3.0, seed=2, columns=360)
    assert main(["odom", str(res.log_path), "-o", str(tmp_path / "plain.tum"), "-q"]) == 0
    trims = []
    real = heap.glibc_trim() or (lambda: 0)
    monkeypatch.setattr(odom_job, "HeapTrim", lambda: heap.HeapTrim(every=1, trim=lambda: trims.append(1) or real()))
    assert main(["odom", str(res.log_path), "-o", str(tmp_path / "trimmed.tum"), "-q"]) == 0
    assert len(trims) == 30
    assert (tmp_path / "trimmed.tum").read_bytes() == (tmp_path / "plain.tum").read_bytes()
