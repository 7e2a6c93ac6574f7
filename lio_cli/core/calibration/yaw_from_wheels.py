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

from dataclasses import dataclass, field, replace

import numpy as np

from ...errors import InputError
from .common import NS_PER_S, CalibrationResult, sandwich_covariance

WINDOW_S = 0.5
GRAVITY_MPS2 = 9.81
MIN_WINDOWS = 12
MIN_ACCEL_MPS2 = 0.1  # rms horizontal acceleration below which no angle shows
LAG_WINDOWS = 8  # neighbouring windows whose errors may be shared (sway, slip)
SCALE_TOLERANCE = 0.2  # |c + i s| this far from 1: the two sides do not measure the same acceleration
SWAY_KEEP = 0.8  # the sway model is used when it leaves less than this share of the plain fit's rms residual


@dataclass(frozen=True, eq=False)
class WheelYaw(CalibrationResult):
    yaw_rad: float  # rotation about the base z to apply on the left of R_base_imu
    sigma_rad: float
    scale: float  # |c + i s|: near 1 when both sides measure the same accelerations
    windows: int
    rms_accel_mps2: float  # of the wheels' horizontal accelerations
    rms_residual_mps2: float
    notes: tuple[str, ...]
    lever_xy_m: np.ndarray = field(default_factory=lambda: np.zeros(2))  # the IMU origin in the base x-y plane (r)
    lever_cov_m2: np.ndarray = field(default_factory=lambda: np.full((2, 2), np.inf))


def estimate_wheel_yaw(wheel_stamps_ns: np.ndarray, speed_mps: np.ndarray, yaw_rate_radps: np.ndarray,
                       imu_stamps_ns: np.ndarray, accel_mps2: np.ndarray, *, R_base_imu: np.ndarray,
                       imu_time_offset_s: float = 0.0, exclude_ns: tuple = (),
                       gyro_radps: np.ndarray | None = None, gyro_bias_radps: np.ndarray | None = None,
                       min_accel_mps2: float = MIN_ACCEL_MPS2) -> WheelYaw:
    """Yaw correction of ``R_base_imu`` (see ``_fit``). With the gyro, the fit without the sway model runs too:
    when the sway model does not lower the residual clearly (``SWAY_KEEP``: a level robot, whose integrated gyro
    is noise), the plain fit is the estimate; else the two estimates' difference joins the 1-sigma: the residuals
    of the richer model alone understated its error about fivefold on a simulated car (0.69 deg off at 1-sigma
    0.09)."""
    args = (wheel_stamps_ns, speed_mps, yaw_rate_radps, imu_stamps_ns, accel_mps2, R_base_imu, imu_time_offset_s,
            exclude_ns, min_accel_mps2)
    res = _fit(*args, gyro_radps, gyro_bias_radps)
    if gyro_radps is None:
        return res
    plain = _fit(*args, None, None)
    if res.rms_residual_mps2 >= SWAY_KEEP * plain.rms_residual_mps2:  # no sway the accelerations show: the gyro's
        return replace(plain, notes=(*plain.notes, "no body sway modelled: the gyro's tilt did not explain the "
                                     "accelerations better"))  # integrated noise would only add its own
    spread = float(np.angle(np.exp(1j * (res.yaw_rad - plain.yaw_rad))))
    d = res.lever_xy_m - plain.lever_xy_m
    return replace(res, sigma_rad=float(np.hypot(res.sigma_rad, spread)), lever_cov_m2=res.lever_cov_m2 + np.outer(d, d))


def _fit(wheel_stamps_ns, speed_mps, yaw_rate_radps, imu_stamps_ns, accel_mps2, R_base_imu, imu_time_offset_s,
         exclude_ns, min_accel_mps2, gyro_radps, gyro_bias_radps) -> WheelYaw:
    """Yaw correction of ``R_base_imu`` from wheel speed and yaw rate (already scaled, base frame, LiDAR clock)
    and the accelerometer (IMU clock + ``imu_time_offset_s`` = LiDAR clock); ``exclude_ns``: (start, end)
    stretches to leave out (wheel slip). ``gyro_radps`` (and its bias): the body's
    roll and pitch sway, integrated, is taken out of the horizontal specific force (the gravity it leaks; a
    constant tilt and a linear drift are fitted). InputError when the motion shows too little acceleration or
    the two sides disagree."""
    ws = np.asarray(wheel_stamps_ns, np.int64)
    v, w = np.asarray(speed_mps, float), np.asarray(yaw_rate_radps, float)
    it = np.asarray(imu_stamps_ns, np.int64) + int(round(imu_time_offset_s * NS_PER_S))
    t0, t1 = max(ws[0], it[0]), min(ws[-1], it[-1])
    if t1 <= t0:
        raise InputError("yaw from the wheels' accelerations: the wheels and the IMU do not overlap")
    h = accel_mps2 @ np.asarray(R_base_imu, float).T  # specific force in the base frame (so far)
    tw, ti = (ws - t0) / NS_PER_S, (it - t0) / NS_PER_S
    if gyro_radps is not None:  # tilt phi (roll, pitch) leaks (-g phi_y, g phi_x): taken out
        om = (np.asarray(gyro_radps, float) - (0.0 if gyro_bias_radps is None else gyro_bias_radps)) @ \
            np.asarray(R_base_imu, float).T
        dt = np.diff(ti, prepend=ti[0])
        phi = np.cumsum(om[:, :2] * dt[:, None], axis=0)
        h = h.copy()
        h[:, 0] += GRAVITY_MPS2 * phi[:, 1]
        h[:, 1] -= GRAVITY_MPS2 * phi[:, 0]
        psi = np.cumsum(om[:, 2] * dt)  # heading: a tilt error eps of R_base_imu leaks eps x yaw rate into phi
    bins = np.arange(0.0, (t1 - t0) / NS_PER_S + 1e-9, WINDOW_S / 2)  # half-window bins of means
    m = {k: _window_means(x, ts, bins) for k, (x, ts) in
         {"v": (v, tw), "w": (w, tw), "vw": (v * w, tw), "w2": (w * w, tw), "hx": (h[:, 0], ti),
          "hy": (h[:, 1], ti), "psi": (psi if gyro_radps is not None else 0.0 * ti, ti)}.items()}
    # window k: bins j..j+3 (j = 2k); the speed change between the means of width WINDOW_S around its two ends
    # is the exact (1, 3, 3, 1)/8 triangle average of dv/dt, so the other sides are averaged by that kernel
    j = np.arange(0, len(bins) - 4, 2)
    mid = bins[j + 2] * NS_PER_S + t0
    if exclude_ns:
        j = j[~np.any([(mid > a - WINDOW_S * NS_PER_S) & (mid < b + WINDOW_S * NS_PER_S) for a, b in exclude_ns],
                      axis=0)]
    if len(j) < MIN_WINDOWS:
        raise InputError(f"yaw from the wheels' accelerations: {len(j)} windows of {WINDOW_S:g} s (need {MIN_WINDOWS})")
    diff = lambda x: (x[j + 2] + x[j + 3] - x[j] - x[j + 1]) / (2 * WINDOW_S)  # noqa: E731
    hat = lambda x: (x[j] + 3 * x[j + 1] + 3 * x[j + 2] + x[j + 3]) / 8  # noqa: E731
    a_fwd, dw = diff(m["v"]), diff(m["w"])
    a_lat, w2, hx, hy = hat(m["vw"]), hat(m["w2"]), hat(m["hx"]), hat(m["hy"])
    n = len(a_fwd)
    zero, one = np.zeros(n), np.ones(n)
    # unknowns: c, s, b_x, b_y, r_x, r_y; rows: the x (forward) and y (left) accelerations
    Jx = np.column_stack([hx, -hy, -one, zero, -w2, -dw])
    Jy = np.column_stack([hy, hx, zero, -one, dw, -w2])
    if gyro_radps is not None:  # the integrated tilt's drift (a gyro bias error): linear in time
        tc, gp = bins[j + 2] - bins[j + 2].mean(), GRAVITY_MPS2 * hat(m["psi"])
        Jx, Jy = np.column_stack([Jx, tc, zero, gp, zero]), np.column_stack([Jy, zero, tc, zero, gp])
    J = np.stack([Jx, Jy], axis=1)  # (n, 2, p)
    y = np.stack([a_fwd, a_lat], axis=1)
    rms_a = float(np.sqrt((y * y).sum(axis=1).mean()))
    if rms_a < min_accel_mps2:
        raise InputError(f"yaw from the wheels' accelerations: too little acceleration (rms {rms_a:.2f} m/s^2, need "
                         f"{min_accel_mps2:g}): speed up, brake and turn")
    A = J.reshape(-1, J.shape[2])
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
                    rms_residual_mps2=float(np.sqrt((r * r).mean())), notes=(), lever_xy_m=-x[4:6],
                    lever_cov_m2=cov[4:6, 4:6].copy())


def _window_means(x: np.ndarray, ts: np.ndarray, edges: np.ndarray) -> np.ndarray:
    """Mean of the samples ``x`` (at ``ts``) in each window [edges[k], edges[k+1]); an empty one interpolated."""
    k = np.searchsorted(ts, edges)
    c = np.concatenate([[0.0], np.cumsum(x)])
    n = np.diff(k)
    mid = 0.5 * (edges[:-1] + edges[1:])
    return np.where(n > 0, (c[k[1:]] - c[k[:-1]]) / np.maximum(n, 1), np.interp(mid, ts, x))


def fit_wheel_sway_yaw(wheel_stamps_ns: np.ndarray, speed_mps: np.ndarray, yaw_rate_radps: np.ndarray,
                       imu_stamps_ns: np.ndarray, accel_mps2: np.ndarray, gyro_radps: np.ndarray, *,
                       R_base_imu: np.ndarray, gyro_bias_radps: np.ndarray | None = None,
                       imu_time_offset_s: float = 0.0, exclude_ns: tuple = (),
                       min_accel_mps2: float = MIN_ACCEL_MPS2) -> WheelYaw:
    """The fit with the body's sway taken out (``_fit`` with the gyro) alone, its 1-sigma the residuals' own:
    for a caller that judges the yaw's uncertainty itself (a straight drive's plain fit, which
    ``estimate_wheel_yaw`` compares with, reads the body's pitch under braking as degrees of yaw)."""
    return _fit(wheel_stamps_ns, speed_mps, yaw_rate_radps, imu_stamps_ns, accel_mps2, R_base_imu, imu_time_offset_s,
                exclude_ns, min_accel_mps2, gyro_radps, gyro_bias_radps)
