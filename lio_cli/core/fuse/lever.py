"""The IMU's readings moved to the base origin: angular rate and specific force in base axes, lever arm removed.

``f_base = R_bi f_imu - (alpha x r + w x (w x r))``, ``r`` the IMU origin in base, ``alpha`` the angular
acceleration. ``alpha`` is not measured: it is the slope of the gyro, and the slope of white noise grows as
the step shrinks, so a three-point derivative times a long lever arm buries the accelerometer's own noise.
Here ``alpha`` is the slope of a straight line fitted to the gyro over +-``ALPHA_HALF_WINDOW_NS`` around each
sample: its noise is ``sigma_w * sqrt(12 / (dt^2 N (N^2 - 1)))`` for N samples ``dt`` apart. The window costs
accuracy only where large angular accelerations change within it *and* the lever arm is long; leaving
``alpha`` out altogether is worse.
"""

from __future__ import annotations

import numpy as np

from .inputs import ImuSeries

ALPHA_HALF_WINDOW_NS = 50_000_000  # +-50 ms: see the module's docstring
MAX_WINDOW_SIDE = 100  # samples on each side at most (a 2 kHz IMU fills +-50 ms): bounded cost on any stamps


def angular_acceleration(stamps_ns: np.ndarray, w: np.ndarray, half_window_ns: int = ALPHA_HALF_WINDOW_NS) -> np.ndarray:
    """(N,3) slope of ``w`` (N,3) at each sorted, distinct stamp: least-squares line through the samples
    within ``half_window_ns`` of it (never across a gap longer than that; at most ``MAX_WINDOW_SIDE`` a side).
    Zero where the window holds no other sample."""
    n = len(stamps_ns)
    alpha = np.zeros((n, 3))
    if n < 2:
        return alpha
    st = np.asarray(stamps_ns, np.int64)
    idx = np.arange(n)
    reach = max(int((np.searchsorted(st, st + half_window_ns, side="right") - idx - 1).max()),
                int((idx - np.searchsorted(st, st - half_window_ns, side="left")).max()))
    reach = min(reach, MAX_WINDOW_SIDE)
    s0 = np.ones(n)
    s1, s2 = np.zeros(n), np.zeros(n)
    sw, stw = np.zeros((n, 3)), np.zeros((n, 3))
    for k in (*range(-reach, 0), *range(1, reach + 1)):
        a, b = max(0, -k), min(n, n - k)  # centres i in [a, b) have a neighbour i + k
        dt_ns = st[a + k:b + k] - st[a:b]
        ok = np.abs(dt_ns) <= half_window_ns
        dt = np.where(ok, dt_ns * 1e-9, 0.0)
        dw = np.where(ok[:, None], w[a + k:b + k] - w[a:b], 0.0)  # relative to the centre: no cancellation
        s0[a:b] += ok
        s1[a:b] += dt
        s2[a:b] += dt * dt
        sw[a:b] += dw
        stw[a:b] += dt[:, None] * dw
    den = s0 * s2 - s1 * s1  # s0 * sum((dt - mean)^2): zero only when the window holds the centre alone
    has = den > 0.0
    alpha[has] = (s0[has, None] * stw[has] - s1[has, None] * sw[has]) / den[has, None]
    return alpha


def imu_in_base(imu: ImuSeries) -> tuple[np.ndarray, np.ndarray]:
    """Angular rate and specific force of the base origin in base axes, lever arm removed (module docstring)."""
    R_bi, r = imu.T_base_imu[:3, :3], imu.T_base_imu[:3, 3]
    w = imu.gyro_radps @ R_bi.T
    f = imu.accel_mps2 @ R_bi.T
    if np.any(r) and len(w) > 1:
        alpha = angular_acceleration(imu.stamps_ns, w)
        f = f - np.cross(alpha, r) - np.cross(w, np.cross(w, r))
    return w, f
