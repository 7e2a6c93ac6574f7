"""The C heap trimmed after each batch run: once per run (failed ones too), a no-op without glibc, memory really
handed back."""

from __future__ import annotations

import ctypes
import os
import sys

import numpy as np
import pytest

import lio_cli.heap as heap
import lio_cli.batch.runs as runs
from lio_cli.config.odom import OdomConfig


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


def _task(log, tmp_path) -> runs.RunTask:
    return runs.RunTask("r1", "odom", log, None, None, OdomConfig(), tmp_path / "out")


def test_a_batch_worker_trims_the_heap_after_each_run(tmp_path, monkeypatch):
    calls = []
    monkeypatch.setattr(runs, "trim_heap", lambda: calls.append(1) or True)
    monkeypatch.setattr(runs, "_execute", lambda task, here, t0: (calls.append("ran"), {"status": "ok"})[1])
    assert runs.execute(_task(tmp_path / "a.bag", tmp_path)) == {"status": "ok"}
    assert runs.execute(_task(tmp_path / "b.bag", tmp_path)) == {"status": "ok"}
    assert calls == ["ran", 1, "ran", 1]


def test_a_failed_batch_run_trims_the_heap_too(tmp_path, monkeypatch):
    calls = []
    monkeypatch.setattr(runs, "trim_heap", lambda: calls.append(1) or True)
    rec = runs.execute(_task(tmp_path / "missing.bag", tmp_path))
    assert rec["status"] == "failed" and rec["exit_code"] == 2, rec
    assert calls == [1]
