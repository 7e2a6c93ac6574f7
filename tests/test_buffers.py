"""Pooled arrays: a buffer is handed out again only once nothing refers to it, so no array's content changes."""

from __future__ import annotations

import numpy as np

from lio_cli.buffers import MIN_POOLED_BYTES, ArrayPool, release_idle_buffers


def test_a_buffer_seen_by_a_view_is_not_reused():
    pool = ArrayPool(keep=4)
    a = pool.empty((10_000, 3))
    a[:] = np.arange(30_000).reshape(-1, 3)
    kept = a[5:7]  # a view of a view: still the pooled buffer's
    del a
    b = pool.empty((10_000, 3))
    b[:] = -1.0
    assert kept.tolist() == [[15.0, 16.0, 17.0], [18.0, 19.0, 20.0]]
    assert not np.shares_memory(kept, b)
    del kept, b
    c = pool.empty((9_000, 3))  # both buffers idle now: one of them again, no new one
    assert pool.allocated == 2 and any(np.shares_memory(c, buf) for buf in pool.bufs)


def test_arrays_after_reuse_hold_what_was_written_in_their_shape_and_type():
    pool = ArrayPool(keep=2)
    rng = np.random.default_rng(0)
    for n in (20_000, 17_000, 21_000, 30_000, 9_000):
        xyz = pool.empty((n, 3))
        stamps = pool.empty(n, np.int64)
        want_xyz, want_stamps = rng.normal(size=(n, 3)), rng.integers(0, 2**62, n)
        xyz[:], stamps[:] = want_xyz, want_stamps
        assert xyz.shape == (n, 3) and xyz.dtype == np.float64 and xyz.flags.c_contiguous
        assert stamps.shape == (n,) and stamps.dtype == np.int64
        assert np.array_equal(xyz, want_xyz) and np.array_equal(stamps, want_stamps)
    assert pool.allocated < 10  # buffers came back


def test_small_requests_and_a_full_pool_give_plain_arrays():
    pool = ArrayPool(keep=1)
    small = pool.empty(MIN_POOLED_BYTES // 8 - 1)
    assert small.base is None and not pool.bufs
    first = pool.empty(MIN_POOLED_BYTES // 8)
    second = pool.empty(MIN_POOLED_BYTES // 8)  # the one buffer is in use
    assert first.base is pool.bufs[0] and second.base is None and pool.allocated == 1


def test_a_full_pool_of_far_larger_idle_buffers_gives_one_up():
    """After a big log, a worker's small requests replace an idle oversized buffer instead of being served plain
    arrays forever beside it."""
    pool = ArrayPool(keep=2)
    big = [pool.empty(1_000_000), pool.empty(1_000_000)]  # 8 MB each
    del big
    small = pool.empty(MIN_POOLED_BYTES // 8)
    assert small.base is not None and any(np.shares_memory(small, b) for b in pool.bufs)
    assert sorted(len(b) for b in pool.bufs) == [MIN_POOLED_BYTES, 8 * 2**20]


def test_idle_buffers_are_released_and_held_ones_kept():
    pool = ArrayPool(keep=4)
    held = pool.empty(100_000)
    held[:] = 7.0
    idle = pool.empty(100_000)
    del idle
    release_idle_buffers()
    assert len(pool.bufs) == 1 and np.shares_memory(held, pool.bufs[0]) and (held == 7.0).all()


def test_numpy_integer_shapes_are_sizes_like_ints():
    pool = ArrayPool(keep=1)
    a = pool.empty((np.int64(3), np.int64(10_000)))
    assert a.shape == (3, 10_000) and a.base is pool.bufs[0]
