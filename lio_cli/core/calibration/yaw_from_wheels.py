"""The IMU's mounting yaw about the base's vertical from accelerations the wheels give (GRIL-Calib's idea).

A vehicle turning about its vertical only hides that angle from the gyro; its accelerations show it. The wheels
measure them in the base frame without any registration noise: forward ``dv/dt`` and centripetal ``v w``. The
IMU's specific force, put into the base frame through the mounting so far (``R_base_imu``, its roll and pitch
right), has the same horizontal part turned by the yaw error ``d``, less a constant bias, plus the lever arm's
``w^2 r`` and ``dw/dt x r``. Over windows of ``WINDOW_S`` (both sides averaged alike: the average of ``dv/dt`` is
exactly the speed change over the window)

    a_xy = [[c, -s], [s, c]] h_xy - b_xy + L(w) r_xy

is linear in (c, s, b, r); ``d = atan2(s, c)``. Its 1-sigma comes from the residuals (sandwich over a few
neighbouring windows: a body's sway leaks gravity slowly), never from an assumed noise level.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ...errors import InputError
from .common import NS_PER_S, CalibrationResult, sandwich_covariance

WINDOW_S = 0.5
MIN_WINDOWS = 12
MIN_ACCEL_MPS2 = 0.1  # rms horizontal acceleration below which no angle shows
LAG_WINDOWS = 2  # neighbouring windows whose errors may be shared (sway, slip)
SCALE_TOLERANCE = 0.2  # |c + i s| this far from 1: the two sides do not measure the same acceleration


@dataclass(frozen=True, eq=False)
class WheelYaw(CalibrationResult):
    yaw_rad: float  # rotation about the base z to apply on the left of R_base_imu
    sigma_rad: float
    scale: float  # |c + i s|: near 1 when both sides measure the same accelerations
    windows: int
    rms_accel_mps2: float  # of the wheels' horizontal accelerations
    rms_residual_mps2: float
    notes: tuple[str, ...]


def estimate_wheel_yaw(wheel_stamps_ns: np.ndarray, speed_mps: np.ndarray, yaw_rate_radps: np.ndarray,
                       imu_stamps_ns: np.ndarray, accel_mps2: np.ndarray, *, R_base_imu: np.ndarray,
                       imu_time_offset_s: float = 0.0) -> WheelYaw:
    """Yaw correction of ``R_base_imu`` from wheel speed and yaw rate (already scaled, base frame, LiDAR clock)
    and the accelerometer (IMU clock + ``imu_time_offset_s`` = LiDAR clock). InputError when the motion shows
    too little acceleration or the two sides disagree."""
    ws = np.asarray(wheel_stamps_ns, np.int64)
    v, w = np.asarray(speed_mps, float), np.asarray(yaw_rate_radps, float)
    it = np.asarray(imu_stamps_ns, np.int64) + int(round(imu_time_offset_s * NS_PER_S))
    t0, t1 = max(ws[0], it[0]), min(ws[-1], it[-1])
    edges = np.arange(t0, t1, int(WINDOW_S * NS_PER_S))
    if len(edges) - 1 < MIN_WINDOWS:
        raise InputError(f"yaw from the wheels' accelerations: the wheels and the IMU overlap {len(edges) - 1} "
                         f"windows of {WINDOW_S:g} s (need {MIN_WINDOWS})")
    h = accel_mps2 @ np.asarray(R_base_imu, float).T  # specific force in the base frame (so far)
    tw, ti = (ws - t0) / NS_PER_S, (it - t0) / NS_PER_S
    e = (edges - t0) / NS_PER_S
    v_e, w_e = np.interp(e, tw, v), np.interp(e, tw, w)
    a_fwd = np.diff(v_e) / WINDOW_S  # exact window average of dv/dt
    dw = np.diff(w_e) / WINDOW_S
    a_lat, w2 = _window_means(v * w, tw, e), _window_means(w * w, tw, e)
    hx, hy = _window_means(h[:, 0], ti, e), _window_means(h[:, 1], ti, e)
    n = len(a_fwd)
    zero, one = np.zeros(n), np.ones(n)
    # unknowns: c, s, b_x, b_y, r_x, r_y; rows: the x (forward) and y (left) accelerations
    Jx = np.column_stack([hx, -hy, -one, zero, -w2, -dw])
    Jy = np.column_stack([hy, hx, zero, -one, dw, -w2])
    J = np.stack([Jx, Jy], axis=1)  # (n, 2, 6)
    y = np.stack([a_fwd, a_lat], axis=1)
    rms_a = float(np.sqrt((y * y).sum(axis=1).mean()))
    if rms_a < MIN_ACCEL_MPS2:
        raise InputError(f"yaw from the wheels' accelerations: too little acceleration (rms {rms_a:.2f} m/s^2, need "
                         f"{MIN_ACCEL_MPS2:g}): speed up, brake and turn")
    A = J.reshape(-1, 6)
    x = np.linalg.lstsq(A, y.reshape(-1), rcond=None)[0]
    r = y - J @ x
    H = A.T @ A
    scores = np.einsum("nji,nj->ni", J, r)
    cov = sandwich_covariance(H, scores, lag=min(LAG_WINDOWS, n // 4))
    c, s = x[0], x[1]
    scale = float(np.hypot(c, s))
    if abs(scale - 1.0) > SCALE_TOLERANCE:
        raise InputError(f"yaw from the wheels' accelerations: the IMU's horizontal accelerations are {scale:.2f} "
                         "times the wheels' (a slipping or mis-scaled wheel odometry, or a base that is not level)")
    g = np.array([-s, c]) / scale**2  # gradient of atan2(s, c)
    sigma = float(np.sqrt(max(g @ cov[:2, :2] @ g, 0.0)))
    return WheelYaw(yaw_rad=float(np.arctan2(s, c)), sigma_rad=sigma, scale=scale, windows=n, rms_accel_mps2=rms_a,
                    rms_residual_mps2=float(np.sqrt((r * r).mean())), notes=())


def _window_means(x: np.ndarray, ts: np.ndarray, edges: np.ndarray) -> np.ndarray:
    """Mean of the samples ``x`` (at ``ts``) in each window [edges[k], edges[k+1]); an empty one interpolated."""
    k = np.searchsorted(ts, edges)
    c = np.concatenate([[0.0], np.cumsum(x)])
    n = np.diff(k)
    mid = 0.5 * (edges[:-1] + edges[1:])
    return np.where(n > 0, (c[k[1:]] - c[k[:-1]]) / np.maximum(n, 1), np.interp(mid, ts, x))
