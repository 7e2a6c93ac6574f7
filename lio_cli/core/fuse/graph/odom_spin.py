"""How far the odometry's rotation increments scatter about the gyro's, measured on the log.

An odometry file without covariances gets the default per-pose sigma (``NoiseOptions.odom_rotation_sigma_rad``),
and its increments in the graph a share of it (``factors.ODOM_DELTA_SHARE``): 0.7 mrad per 0.1 s, a heading
random walk of 15 mrad over 45 s. A scan matcher's heading drifts by far less, and then a consumer receiver's
slow error (or the wheels' yaw) turns the whole track at almost no cost. Between two odometry poses the gyro
turns by its rates' integral plus its bias times the interval: the residual of the odometry's rotation vector
against that, less a bias per ``WINDOW_S`` (median), scatters by the odometry's increment noise and the gyro's
white noise: its robust sigma (the largest axis's) bounds what the increments are worth.
"""

from __future__ import annotations

import numpy as np

from ....so3 import so3_log_batch
from ...imu import running_integral
from ...robust import robust_sigma

WINDOW_S = 10.0  # the gyro's bias: one per this long a stretch (it wanders slowly)
MIN_INCREMENTS = 50  # fewer pairs with the gyro across them: nothing measured
MIN_PER_WINDOW = 10  # a window's median bias taken out of fewer increments would take their scatter with it
MIN_SIGMA_RAD = 5e-5  # the measured sigma is never taken below this (what 0.1 s of a gyro resolves)
MARGIN = 4.0  # an increment's rotation sigma at most this many times the measured one (graph and planar filter)


def increment_sigma(prep, idx: np.ndarray) -> float | None:
    """The rotation sigma (rad, the largest axis's) of the odometry's increments between its poses ``idx``
    (consecutive), from their scatter about the gyro's, or None without enough of them over gap-free IMU data (at
    least ``MIN_PER_WINDOW`` in a window)."""
    od, imu = prep.odom, prep.imu
    w = getattr(prep, "imu_w_b", None)
    if imu is None or w is None or len(idx) < MIN_INCREMENTS + 1:
        return None
    t = imu.stamps_ns
    ts = (t - t[0]) * 1e-9
    cum = running_integral(ts, w)
    a, b = od.stamps_ns[idx[:-1]], od.stamps_ns[idx[1:]]
    ia, ib = np.searchsorted(t, a), np.searchsorted(t, b)
    ok = (a >= t[0]) & (b <= t[-1]) & (b > a)
    ia, ib = np.clip(ia, 1, len(t) - 1), np.clip(ib, 1, len(t) - 1)
    if prep.imu_gap_ns > 0:  # a pair across an IMU gap is not compared
        run = np.r_[0, np.cumsum(np.diff(t) > prep.imu_gap_ns)]
        ok &= run[ia] == run[ib]
    turn = _at(cum, ts, (b - t[0]) * 1e-9, ib) - _at(cum, ts, (a - t[0]) * 1e-9, ia)
    P = od.poses
    R = np.einsum("nji,njk->nik", P[idx[:-1], :3, :3], P[idx[1:], :3, :3])
    rot = so3_log_batch(R)
    dt = (b - a) * 1e-9
    r = (rot - turn)[ok]
    if len(r) < MIN_INCREMENTS:
        return None
    win = ((a[ok] - a[0]) * 1e-9 // WINDOW_S).astype(np.int64)
    rate = r / dt[ok][:, None]  # the bias's share grows with the interval
    keep = np.zeros(len(r), bool)
    for j in np.unique(win).tolist():
        sel = win == j
        if np.count_nonzero(sel) >= MIN_PER_WINDOW:
            r[sel] -= np.median(rate[sel], axis=0) * dt[ok][sel][:, None]
            keep |= sel
    r = r[keep]
    if len(r) < MIN_INCREMENTS:
        return None
    # the gyro's own noise is left in: a bound on the increments' (a configured density can overstate it)
    return float(max(max(robust_sigma(r[:, c]) for c in range(3)), MIN_SIGMA_RAD))


def _at(cum: np.ndarray, ts: np.ndarray, s: np.ndarray, i: np.ndarray) -> np.ndarray:
    """The gyro's integral at seconds ``s``, linear between samples ``i - 1`` and ``i``."""
    t0, t1 = ts[i - 1], ts[i]
    f = np.clip((s - t0) / np.maximum(t1 - t0, 1e-12), 0.0, 1.0)[:, None]
    return cum[i - 1] + f * (cum[i] - cum[i - 1])
