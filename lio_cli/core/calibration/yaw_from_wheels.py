"""The IMU's mounting yaw about the base's vertical from accelerations the wheels give (GRIL-Calib's idea).

A vehicle turning about its vertical only hides that angle from the gyro; its accelerations show it. The wheels
measure them in the base frame without any registration noise: forward ``dv/dt`` and centripetal ``v w``. The
IMU's specific force, put into the base frame through the mounting so far (``R_base_imu``, its roll and pitch
right), has the same horizontal part turned by the yaw error ``d``, less a constant bias, plus the lever arm's
``w^2 r`` and ``dw/dt x r``. Over windows of ``WINDOW_S`` (both sides averaged alike: the average of ``dv/dt`` is
exactly the speed change over the window)

    a_xy = [[c, -s], [s, c]] h_xy - b_xy + L(w) r_xy

is linear in (c, s, b, r); ``d = atan2(s, c)``. With the gyro, the body's tilt is integrated in 3D and the
gravity (and vertical acceleration) it leaks taken out of ``h``, its start tilt and the gyro bias's error fitted
alongside. Its 1-sigma comes from the residuals (sandwich over a few neighbouring windows: a body's sway leaks
gravity slowly) and the gyro's own noise, integrated; never from an assumed noise level.
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace

import numpy as np

from ...errors import InputError
from ...geometry import so3_exp
from ..imu import running_integral
from .common import NS_PER_S, CalibrationResult, sandwich_covariance

WINDOW_S = 0.25  # a ground robot's starts and stops: windows of 0.5 s averaged away a share of them
GRAVITY_MPS2 = 9.81
MIN_WINDOWS = 24  # 6 s of windows
MIN_ACCEL_MPS2 = 0.1  # rms horizontal acceleration below which no angle shows
LAG_WINDOWS = 16  # neighbouring windows (4 s) whose errors may be shared (sway, slip)
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
    is noise), the plain fit is the estimate; else the two estimates' difference joins the yaw's 1-sigma (the
    sway model's residuals alone understated it on a simulated car). Not the lever arm's: the plain
    fit's is decimetres off wherever the sway matters; the caller checks it on the log's halves
    (``halves_scaled``)."""
    args = (wheel_stamps_ns, speed_mps, yaw_rate_radps, imu_stamps_ns, accel_mps2, R_base_imu, imu_time_offset_s,
            exclude_ns, min_accel_mps2)
    res = _fit(*args, gyro_radps, gyro_bias_radps)
    if gyro_radps is None:
        return res
    try:
        plain = _fit(*args, None, None)
    except InputError:  # without the tilt the two sides disagree (a slope, a sway): the tilt explains them
        return res
    if res.rms_residual_mps2 >= SWAY_KEEP * plain.rms_residual_mps2:  # no sway the accelerations show: the gyro's
        return replace(plain, notes=(*plain.notes, "no body sway modelled: the gyro's tilt did not explain the "
                                     "accelerations better"))  # integrated noise would only add its own
    spread = float(np.angle(np.exp(1j * (res.yaw_rad - plain.yaw_rad))))
    return replace(res, sigma_rad=float(np.hypot(res.sigma_rad, spread)))


def halves_scaled(cov_m2: np.ndarray, first: WheelYaw, second: WheelYaw) -> np.ndarray:
    """The lever arm's covariance ``cov_m2`` (of the whole log) scaled, per axis, by how much further apart the two
    halves' fits (``first``, ``second``) are than their own 1-sigmas allow (never below 1): the residuals alone
    miss what follows a drive's phases (a cruising half pins the lateral lever arm poorly), and the plain half
    difference would gate an axis the other half pins to a centimetre."""
    d = second.lever_xy_m - first.lever_xy_m
    spread = np.diag(first.lever_cov_m2) + np.diag(second.lever_cov_m2)
    k = np.sqrt(np.maximum(1.0, d**2 / np.maximum(spread, 1e-12)))
    return np.asarray(cov_m2, float) * np.outer(k, k)


def _fit(wheel_stamps_ns, speed_mps, yaw_rate_radps, imu_stamps_ns, accel_mps2, R_base_imu, imu_time_offset_s,
         exclude_ns, min_accel_mps2, gyro_radps, gyro_bias_radps, up0=(0.0, 0.0, 1.0), refine: int = 1) -> WheelYaw:
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
    if gyro_radps is not None:  # the body's tilt (its up vector, integrated) leaks gravity: taken out
        om = (np.asarray(gyro_radps, float) - (0.0 if gyro_bias_radps is None else gyro_bias_radps)) @ \
            np.asarray(R_base_imu, float).T
        dt = np.diff(ti, prepend=ti[0])
        up, tilt_cols = _tilt(om, dt, np.asarray(up0, float))
        psi = np.cumsum(om[:, 2] * dt)  # heading
        q = _rate_noise_density2(om[:, :2], float(np.median(np.diff(ti))))
        h = h.copy()
        # f = R^T a_horizontal + (g + a_vertical) up, so f . up is g + a_vertical: a body bouncing on its
        # springs leaks more than g through its roll and pitch
        h[:, :2] -= np.einsum("ni,ni->n", h, up)[:, None] * up[:, :2]
    bins = np.arange(0.0, (t1 - t0) / NS_PER_S + 1e-9, WINDOW_S / 2)  # half-window bins of means
    m = {k: _window_means(x, ts, bins) for k, (x, ts) in
         {"v": (v, tw), "w": (w, tw), "vw": (v * w, tw), "w2": (w * w, tw), "hx": (h[:, 0], ti),
          "hy": (h[:, 1], ti)}.items()}
    if gyro_radps is not None:
        m["psi"] = _window_means(psi, ti, bins)
        m.update({f"t{a}{k}": _window_means(GRAVITY_MPS2 * tilt_cols[:, a, k], ti, bins)
                  for a in range(2) for k in range(tilt_cols.shape[2])})
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
    if gyro_radps is not None:  # the start's tilt and the gyro bias's x, y error, as the up vector's error
        Jx = np.column_stack([Jx, *[hat(m[f"t0{k}"]) for k in range(tilt_cols.shape[2])]])
        Jy = np.column_stack([Jy, *[hat(m[f"t1{k}"]) for k in range(tilt_cols.shape[2])]])
    J = np.stack([Jx, Jy], axis=1)  # (n, 2, p)
    y = np.stack([a_fwd, a_lat], axis=1)
    rms_a = float(np.sqrt((y * y).sum(axis=1).mean()))
    if rms_a < min_accel_mps2:
        raise InputError(f"yaw from the wheels' accelerations: too little acceleration (rms {rms_a:.2f} m/s^2, need "
                         f"{min_accel_mps2:g}): speed up, brake and turn")
    A = J.reshape(-1, J.shape[2])
    x = np.linalg.lstsq(A, y.reshape(-1), rcond=None)[0]
    if gyro_radps is not None and refine > 0:  # the fitted start tilt and bias error, applied: fitted again
        tilt, db = -x[-4:-2], -x[-2:]  # (their effects are not linear over a drive's few degrees of tilt)
        bias = (0.0 if gyro_bias_radps is None else np.asarray(gyro_bias_radps, float)) - \
            np.array([db[0], db[1], 0.0]) @ np.asarray(R_base_imu, float)
        return _fit(wheel_stamps_ns, speed_mps, yaw_rate_radps, imu_stamps_ns, accel_mps2, R_base_imu,
                    imu_time_offset_s, exclude_ns, min_accel_mps2, gyro_radps, bias,
                    np.asarray(up0, float) + np.array([tilt[0], tilt[1], 0.0]), refine - 1)
    r = y - J @ x
    H = A.T @ A
    # each window's residual freed of its own pull on the fit (HC3): with 10 unknowns over a few dozen windows the
    # residuals alone understate the error
    L = np.einsum("nai,ij,nbj->nab", J, np.linalg.inv(H), J)
    scores = np.einsum("nji,nj->ni", J, np.linalg.solve(np.eye(2) - L, r[..., None])[..., 0])
    cov = sandwich_covariance(H, scores, lag=min(LAG_WINDOWS, n // 4))
    if gyro_radps is not None:  # the gyro's noise, integrated into the tilt, wanders: a slow error the residuals
        cov = cov + _tilt_walk_cov(A, H, bins[j + 2] - ti[0], hat(m["psi"]), q)  # cannot tell from the motion
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


def _tilt_walk_cov(A: np.ndarray, H: np.ndarray, t: np.ndarray, psi: np.ndarray, q: float) -> np.ndarray:
    """Covariance of the fit's unknowns from the integrated tilt's random walk: the up vector's error (start frame)
    has covariance ``q`` min(t_i, t_j) per axis, turned into the base frame at each window's heading ``psi``; the
    horizontal specific force's error is g times it. min(t_i, t_j) is a sum of the time steps up to the earlier
    window and the turn from window i to j a product of the two headings' rotations, so the sum over window pairs
    is one over the steps: memory and time linear in the windows."""
    P = np.linalg.solve(H, A.T)  # (p, 2n), window-major columns
    n = len(t)
    Pb = P.reshape(len(P), n, 2).transpose(1, 0, 2)  # (n, p, 2): each window's columns
    c, s = np.cos(psi)[:, None], np.sin(psi)[:, None]
    W = np.stack([Pb[:, :, 0] * c - Pb[:, :, 1] * s, Pb[:, :, 0] * s + Pb[:, :, 1] * c], axis=2)  # P_i Rot(psi_i)^T
    order = np.argsort(t, kind="stable")
    ts = np.asarray(t, float)[order]
    steps = np.diff(np.concatenate([[0.0], ts]))
    G = np.cumsum(W[order][::-1], axis=0)[::-1]  # the windows from each step on
    return GRAVITY_MPS2**2 * q * np.einsum("k,kia,kja->ij", steps, G, G)


def _rate_noise_density2(om_xy: np.ndarray, dt_s: float) -> float:
    """The gyro's white-noise density squared (rad^2/s) about the base x, y axes, read robustly from the
    sample-to-sample differences (the motion is smooth over one sample: the difference is the noise's)."""
    d = np.diff(om_xy, axis=0)
    sd = 1.4826 * np.median(np.abs(d - np.median(d, axis=0)), axis=0) / np.sqrt(2.0)
    return float(np.mean(sd**2) * dt_s)


def _tilt(om: np.ndarray, dt: np.ndarray, up0: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The start's up in the base frame, integrated from the base-frame rates ``om`` (N, 3), and its derivatives
    (N, 2, 4) by a tilt of the start (x, y, in the start frame) and by a gyro bias error (x, y, base frame). A car
    turns through 90 deg and more: a tilt fixed in the world turns in the base frame, and a bias error's tilt
    grows along the heading of the moment, not linearly in the base frame."""
    n = len(om)
    R = np.empty((n, 3, 3))  # R_start_base
    cur = np.eye(3)
    steps = so3_exp(om * dt[:, None])
    for k in range(n):
        cur = cur @ steps[k]
        R[k] = cur
    up = R.transpose(0, 2, 1) @ (up0 / np.linalg.norm(up0))  # R^T up0
    Rt = np.transpose(R, (0, 2, 1))
    theta = np.cumsum(R[:, :, :2] * dt[:, None, None], axis=0)  # start-frame angle error per unit bias x, y
    tz = np.zeros_like(theta)  # theta x e_z
    tz[:, 0], tz[:, 1] = theta[:, 1], -theta[:, 0]
    d_bias = -np.einsum("nij,njk->nik", Rt, tz)
    cols = np.concatenate([Rt[:, :, :2], d_bias], axis=2)  # (n, 3, 4)
    return up, cols[:, :2, :]


def _window_means(x: np.ndarray, ts: np.ndarray, edges: np.ndarray) -> np.ndarray:
    """Mean over each window [edges[k], edges[k+1]) of ``x`` (samples at ``ts``) interpolated linearly between its
    samples, so a window's mean is centred on the window whatever the samples' phase (a plain mean of the samples
    inside is centred on them, up to half a wheel period off, which moves the lever arm at speed)."""
    x = np.broadcast_to(np.asarray(x, float), np.shape(ts))
    c = running_integral(ts, x)  # integral up to each sample
    e = np.clip(edges, ts[0], ts[-1])
    k = np.clip(np.searchsorted(ts, e, side="right") - 1, 0, len(ts) - 2)
    h = np.maximum(ts[k + 1] - ts[k], 1e-12)
    u = e - ts[k]
    ce = c[k] + x[k] * u + 0.5 * (x[k + 1] - x[k]) / h * u * u
    return np.diff(ce) / np.maximum(np.diff(e), 1e-12)


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
