"""GPS as receivers behave, hand-checkable: a multipath jump found and its fixes left out until the track
comes back, a lasting one kept as the new level, an optimistic sigma raised by the innovations."""

from __future__ import annotations

import numpy as np

from lio_cli.core.fuse.gps_quality import JUMP_MAX_S, GpsNoise, find_jumps

NS = 1_000_000_000


def _track(n: int, seed: int = 0, sigma: float = 0.5) -> tuple[np.ndarray, np.ndarray]:
    """5 Hz fixes of a robot at 1.5 m/s heading north-east, white noise ``sigma`` per axis."""
    rng = np.random.default_rng(seed)
    t = np.arange(n) * 0.2
    p = np.column_stack([1.0 * t, 1.1 * t]) + rng.normal(0.0, sigma, (n, 2))
    return (t * NS).astype(np.int64), p


def test_a_multipath_jump_is_left_out_until_the_track_comes_back():
    st, p = _track(300)
    p[100:125] += [7.5, -2.7]  # 8 m for 5 s
    jump, opened, kept = find_jumps(st, p)
    assert np.array_equal(np.flatnonzero(jump), np.arange(100, 125)) and (opened, kept) == (1, 0)
    clean, opened, _ = find_jumps(*_track(300))
    assert not clean.any() and opened == 0  # 0.5 m of white noise opens nothing


def test_a_jump_that_lasts_is_kept_as_the_new_level():
    st, p = _track(600)
    p[100:] += [0.0, 8.0]
    jump, opened, kept = find_jumps(st, p)
    out = np.flatnonzero(jump)
    assert (opened, kept) == (1, 1) and out[0] == 100
    assert abs((st[out[-1]] - st[100]) / NS - JUMP_MAX_S) <= 0.21 and not jump[out[-1] + 1:].any()


def test_an_optimistic_sigma_is_raised_to_what_the_innovations_show():
    rng = np.random.default_rng(1)
    noise = GpsNoise(2)
    claimed = 0.8**2  # a third of the truth, as consumer receivers report
    for _ in range(200):
        assert noise.variance(claimed) >= claimed
        noise.record(rng.normal(0.0, 2.5, 2), 0.1)
    assert abs(np.sqrt(noise.variance(claimed)) - 2.5) < 0.5
    assert noise.variance(9.0) == 9.0  # an honest (or pessimistic) one is kept
