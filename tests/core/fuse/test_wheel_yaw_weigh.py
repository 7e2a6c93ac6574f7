"""``wheel_yaw.weigh`` itself: its per-chunk normal equations give the dense least-squares fit and take memory
linear in the log's length."""

from __future__ import annotations

import tracemalloc

import numpy as np

from lio_cli.core.fuse import wheel_yaw, yaw_fit

NS = 1_000_000_000


def _series(minutes: float, seed: int = 0, wheel_sigma: float = 0.002):
    """(wheel stamps ns, wheel yaw rates, IMU stamps ns, gyro z) of a sine yaw rate; the gyro biased and noisy."""
    rng = np.random.default_rng(seed)
    T = minutes * 60.0
    ti, tw = np.arange(0, T, 1 / 200.0), np.arange(0, T, 1 / 50.0)
    wz = lambda t: 0.3 * np.sin(0.2 * t)  # noqa: E731
    gz = wz(ti) + 0.002 + 0.0005 * ti / T + rng.normal(0, 0.003, len(ti))
    yw = wz(tw) + rng.normal(0, wheel_sigma, len(tw))
    return np.round(tw * NS).astype(np.int64), yw, np.round(ti * NS).astype(np.int64), gz


def _dense(tw_ns, yaw, ti_ns, gz):
    """The fit with the whole design matrix (one row per sample, two columns per chunk): (c, sigma_c, sigma)."""
    tw, ti = (tw_ns - ti_ns[0]) * 1e-9, (ti_ns - ti_ns[0]) * 1e-9
    period = float(np.median(np.diff(tw)))
    G = np.concatenate([[0.0], np.cumsum(0.5 * (gz[1:] + gz[:-1]) * np.diff(ti))])
    g = (np.interp(tw + period / 2, ti, G) - np.interp(tw - period / 2, ti, G)) / period
    ok = (tw - period / 2 >= ti[0]) & (tw + period / 2 <= ti[-1])
    idx = np.flatnonzero(ok)
    chunk = np.floor(tw[idx] / wheel_yaw.CHUNK_S).astype(np.int64)
    _, inv = np.unique(chunk, return_inverse=True)
    m = inv.max() + 1
    X = np.zeros((len(idx), 2 * m + 1))
    X[np.arange(len(idx)), 2 * inv] = 1.0
    X[np.arange(len(idx)), 2 * inv + 1] = tw[idx] - wheel_yaw.CHUNK_S * chunk
    X[:, -1] = g[idx]
    d = g[idx] - yaw[idx]
    keep = np.ones(len(idx), bool)
    for _ in range(yaw_fit.TRIM_PASSES):
        sol = np.linalg.lstsq(X[keep], d[keep], rcond=None)[0]
        r = d - X @ sol
        sigma = 1.4826 * float(np.median(np.abs(r[keep])))
        keep = np.abs(r) <= yaw_fit.TRIM_Z * sigma
    sol = np.linalg.lstsq(X[keep], d[keep], rcond=None)[0]  # c is the last trim's samples' own
    r = d - X @ sol
    sigma = 1.4826 * float(np.median(np.abs(r[keep])))
    s2 = float(r[keep] @ r[keep]) / (int(keep.sum()) - X.shape[1])
    cov = s2 * np.linalg.pinv(X[keep].T @ X[keep])
    return float(sol[-1]), float(np.sqrt(cov[-1, -1])), sigma


def test_the_per_chunk_normal_equations_give_the_dense_fit(monkeypatch):
    tw, yw, ti, gz = _series(3.5)  # four chunks, the last one short
    yw[3000:3040] += 0.2  # trimmed samples too
    monkeypatch.setattr(yaw_fit, "TRIM_EDGE_S", 0.0)  # the dense fit below trims sample by sample ...
    monkeypatch.setattr(yaw_fit, "MIN_BLOCKS", 10**9)  # ... and has only the fit's own sigma
    check, _, _ = wheel_yaw.weigh(tw, yw, ti, gz, 0, 1e-3, 3.0)
    c, c_sigma, sigma = _dense(tw, yw, ti, gz)
    assert abs(check.scale_off - c) < 1e-9 and abs(check.scale_off_sigma / c_sigma - 1) < 1e-6
    assert abs(check.residual_sigma_radps / sigma - 1) < 1e-9


def _peak_bytes(minutes: float) -> int:
    args = _series(minutes)
    tracemalloc.start()
    wheel_yaw.weigh(*args, 0, 1e-3, 3.0)
    peak = tracemalloc.get_traced_memory()[1]
    tracemalloc.stop()
    return peak


def test_memory_is_linear_in_the_log_s_length():
    # measured: 10 min 6.4 MB, 40 min 26 MB (the dense design matrix made it 18 and 246 MB)
    small, large = _peak_bytes(10), _peak_bytes(40)
    assert large < 5 * small


def test_a_noise_free_drive_has_no_far_sample():
    tw, _, ti, _ = _series(2.0)
    # turns that ramp in and out: the rate a wheel message holds and the gyro's mean over its period differ at
    # the ramps' kinks, by up to 1e-3 rad/s, 9000 times the residual's robust sigma
    wz = lambda t: 0.3 * np.sin(0.2 * t) + np.interp(t % 7.0, [0, 1, 2, 4, 5, 7], [0, 0, 0.4, 0.4, 0, 0])  # noqa: E731
    yw, gz = wz(tw * 1e-9), wz(ti * 1e-9) + 0.002  # no noise at all
    check, yaw, _ = wheel_yaw.weigh(tw, yw, ti, gz, 0, 1e-3, 3.9)
    # the gate's floor (the yaw acceleration over half a wheel period) leaves them in; without it 68 were far
    assert check.used and check.far == 0 and np.isfinite(yaw).sum() == len(yw) - check.unchecked == len(yw) - 1


def test_wheel_yaw_rates_without_a_gyro_mean_are_left_out_and_counted():
    tw, yw, ti, gz = _series(2.0)
    hole = (ti >= 30 * NS) & (ti < 31 * NS)  # an IMU gap of a second
    check, yaw, var = wheel_yaw.weigh(tw, yw, ti[~hole], gz[~hole], 20_000_000, 1e-3, 3.9)
    in_gap = (tw > 30 * NS - 10_000_000) & (tw < 31 * NS + 10_000_000)  # their periods cross the gap
    assert check.used and np.isnan(yaw[in_gap]).all()
    # the gap's 51 and the first, whose period starts before the IMU's first sample
    assert check.unchecked == in_gap.sum() + 1 == 52 and check.to_dict()["unchecked_samples"] == 52
    assert np.isfinite(yaw).sum() == len(yw) - check.unchecked - check.far
