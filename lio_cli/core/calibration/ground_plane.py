"""A ground vehicle's IMU roll, pitch (and yaw) on its base from the planar-motion constraint (GRIL-Calib's idea).

A car or a ground robot on level ground turns about its base's vertical only, so the vertical stays put in
the base frame. Carried along by the gyro through the mounting so far (``R_base_imu``), a vector fixed in the
world, started near the base's vertical, stays within the body's sway of one place; a mounting tilted by
``eps`` (``R_est = exp(eps) R_true``) holds it at ``eps x e_z`` instead of on the axis, while the start's own
error turns with the heading. So, with ``Phi(t)`` the gyro's rotation from the first sample to ``t`` in the
base frame,

    P_xy Phi(t)^T (e_z + d) = w + s(t)

is linear in the start's tilt ``d`` and the constant ``w`` (``eps_x = -w_y``, ``eps_y = w_x``); the sway ``s``
is the residual, and a gyro bias the motion left (three more unknowns, their effect linearised) drifts it.
The heading must change for ``d`` and ``w`` to part: a straight drive leaves them together. The LiDAR is not
needed. With the wheels, the sway ``s`` itself is taken out: the accelerometer less the wheels' forward and
centripetal accelerations shows it, up to a constant holding the accelerometer's bias (0.04 m/s^2 reads as
0.23 deg of tilt) and the tilt, so only its changes are used; that side also fits the mounting's yaw (the
specific force turned against the wheels' accelerations), the lever arm's terms and the IMU's clock against the
wheels'. The 1-sigma is residual-scaled (sandwich over neighbouring samples: sway is slow), never assumed, plus
the body's unknown mean tilt over the log (what level ground on average leaves open).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ...errors import InputError
from .common import NS_PER_S, CalibrationResult, sandwich_covariance
from .signals import GyroOrientation

SAMPLE_S = 0.1  # the gyro's orientation is read this often
LAG_S = 3.0  # sway this slow is shared by neighbouring samples (the sandwich's lag)
MIN_SAMPLES = 50
MAX_SWAY_RAD = np.radians(2.0)  # rms residual above which the motion is not planar (a hand-held sweep, a ramp)
BIAS_STEP_RADPS = 1e-4  # the bias's linearisation step
BIAS_PRIOR_RADPS = 0.01  # 1-sigma of the gyro bias given, when not said
BIAS_FLOOR_RADPS = 1e-4
MEAN_LAG_S = 5.0  # the body's sway is this slow at most (a car's on its springs): how well its mean is known
SMOOTH_S = 0.5  # both sides' accelerations are averaged over +-this (a triangle): wheel speeds differentiate noisily
GRAVITY_MPS2 = 9.81


@dataclass(frozen=True, eq=False)
class PlanarTilt(CalibrationResult):
    tilt_rad: np.ndarray  # (2,) eps about the base x, y: R_base_imu -> exp(-eps) R_base_imu corrects it
    covariance_rad2: np.ndarray  # (2,2)
    sigma_rad: np.ndarray  # (2,)
    heading_spread_rad: float  # max - min of the heading over the samples
    rms_sway_rad: float  # of the residual
    samples: int
    notes: tuple[str, ...]
    yaw_rad: float = float("nan")  # with the accelerometer: the yaw to apply on the left of R_base_imu (about base z)
    yaw_sigma_rad: float = float("nan")
    covariance3_rad2: np.ndarray | None = None  # (3,3) of (eps_x, eps_y, -yaw) with the accelerometer
    rms_accel_mps2: float = 0.0  # of the wheels' horizontal accelerations over the samples kept


def estimate_planar_tilt(imu_stamps_ns: np.ndarray, gyro_radps: np.ndarray, *, R_base_imu: np.ndarray,
                         gyro_bias_radps: np.ndarray | None = None, max_sway_rad: float = MAX_SWAY_RAD,
                         accel_mps2: np.ndarray | None = None, wheels: tuple | None = None,
                         imu_time_offset_s: float = 0.0, exclude_ns: tuple = (),
                         gyro_bias_sigma_radps: np.ndarray | None = None) -> PlanarTilt:
    """Roll and pitch error of ``R_base_imu`` (maps IMU vectors into the base frame) from the gyro of a vehicle
    turning about its base z (see the module). With ``accel_mps2`` and ``wheels`` = (stamps on the LiDAR clock,
    forward speed, yaw rate, both scaled), the body's sway the accelerometer shows (its specific force less the
    wheels' accelerations) is taken out of the residual: only its changes, so its bias stays out. InputError
    when the samples are too few or the motion is not planar (the residual's rms above ``max_sway_rad``).
    ``exclude_ns``: (start, end) LiDAR-clock stretches where the wheels slipped, left out.
    ``gyro_bias_sigma_radps``: how well the bias given is known (a prior; default ``BIAS_PRIOR_RADPS``)."""
    s = np.asarray(imu_stamps_ns, np.int64)
    gyro = np.asarray(gyro_radps, float)
    if len(s) < 10 or (s[-1] - s[0]) / NS_PER_S < MIN_SAMPLES * SAMPLE_S:
        raise InputError(f"roll and pitch from planar motion: {(s[-1] - s[0]) / NS_PER_S if len(s) else 0:.1f} s of "
                         f"gyro (need {MIN_SAMPLES * SAMPLE_S:g})")
    Rbi = np.asarray(R_base_imu, float)
    b0 = np.zeros(3) if gyro_bias_radps is None else np.asarray(gyro_bias_radps, float)
    ti = (s - s[0]) / NS_PER_S
    t = np.arange(0.0, ti[-1], SAMPLE_S)
    if wheels is not None and accel_mps2 is not None:  # the wheels' span only
        tw = (np.asarray(wheels[0], np.int64) - s[0]) / NS_PER_S - imu_time_offset_s
        t = t[(t >= max(tw[0], 0.0) + SMOOTH_S) & (t <= min(tw[-1], ti[-1]) - SMOOTH_S)]
        if len(t) < MIN_SAMPLES:
            raise InputError(f"roll and pitch from planar motion: the wheels and the IMU overlap {len(t) * SAMPLE_S:.1f} s "
                             f"(need {MIN_SAMPLES * SAMPLE_S:g})")

    def up_columns(bias: np.ndarray) -> np.ndarray:  # (n, 3, 3): Phi(t)^T in the base frame
        G = GyroOrientation(s, gyro, bias).at(t)
        return Rbi @ np.transpose(G, (0, 2, 1)) @ Rbi.T

    Phi = up_columns(b0)
    base = Phi[:, :2, 2]  # P_xy Phi^T e_z
    cols = [Phi[:, :2, 0], Phi[:, :2, 1], -np.tile(np.eye(2)[0], (len(t), 1)), -np.tile(np.eye(2)[1], (len(t), 1))]
    for k in range(3):  # a bias left in the gyro: its effect on P_xy Phi^T e_z, per unit
        db = np.zeros(3)
        db[k] = BIAS_STEP_RADPS
        cols.append((up_columns(b0 + db)[:, :2, 2] - base) / BIAS_STEP_RADPS)
    n_gyro = len(cols)
    if wheels is not None and accel_mps2 is not None:
        sway, acc_cols = _accel_sway(t, ti, np.asarray(accel_mps2, float) @ Rbi.T, tw, wheels)
        cols += [sway, *acc_cols]
        wheel_accel = _wheel_accel(t, tw, wheels)
    keep = np.ones(len(t), bool)
    for a, b in exclude_ns:  # computed over the whole grid first: the accelerations differentiate it
        a, b = (np.array([a, b], np.int64) - s[0]) / NS_PER_S - imu_time_offset_s
        keep &= (t < a - 2 * SMOOTH_S) | (t > b + 2 * SMOOTH_S)
    if keep.sum() < MIN_SAMPLES:
        raise InputError(f"roll and pitch from planar motion: {keep.sum()} samples outside the wheels' slips (need "
                         f"{MIN_SAMPLES})")
    t, base, cols, Phi = t[keep], base[keep], [c[keep] for c in cols], Phi[keep]
    mean_var = np.zeros((2, 2))
    rms_a = float(np.sqrt((wheel_accel[keep] ** 2).sum(axis=1).mean())) if len(cols) > n_gyro else 0.0
    if len(cols) > n_gyro:  # the accelerometer's, less their means over the samples kept (the bias, the tilt)
        acc = [c - c.mean(axis=0) for c in cols[n_gyro:]]
        base, cols = base - acc[0], cols[:n_gyro] + acc[1:]
        # ...and so the body's mean tilt over the log is taken as level: what its sway leaves of that unknown
        mean_var = sandwich_covariance(np.eye(2) * len(t), acc[0], lag=max(1, int(round(MEAN_LAG_S / SAMPLE_S))))
    J = np.stack(cols, axis=2)  # (n, 2, p): d_x, d_y, w_x, w_y, bias x3 (and the accelerometer's yaw, lever arm)
    A = J.reshape(-1, J.shape[2])
    y = -base.reshape(-1)
    # the bias correction has a prior (whitened by the residual's own level, found by a first solve)
    bsig = np.full(3, BIAS_PRIOR_RADPS) if gyro_bias_sigma_radps is None else \
        np.maximum(np.nan_to_num(np.asarray(gyro_bias_sigma_radps, float), nan=BIAS_PRIOR_RADPS), BIAS_FLOOR_RADPS)
    prior = np.zeros((A.shape[1], A.shape[1]))
    noise = 1.0
    for _ in range(2):
        prior[4:7, 4:7] = np.diag(noise**2 / bsig**2)
        x = np.linalg.solve(A.T @ A + prior, A.T @ y)
        r = (y - A @ x).reshape(-1, 2)
        noise = float(np.sqrt((r * r).mean()))
    rms = float(np.sqrt((r * r).sum(axis=1).mean()))
    heading = np.unwrap(np.arctan2(Phi[:, 1, 0], Phi[:, 0, 0]))
    spread = float(heading.max() - heading.min())
    if rms > max_sway_rad:
        raise InputError(f"roll and pitch from planar motion: the vertical moves {np.degrees(rms):.1f} deg rms in the "
                         f"base frame (at most {np.degrees(max_sway_rad):g}): the platform does not turn about its "
                         "base z only (not a ground vehicle on level ground, or the base frame is not on the ground)")
    H = A.T @ A + prior
    scores = np.einsum("nji,nj->ni", J, r)
    cov = sandwich_covariance(H, scores, lag=max(1, int(round(LAG_S / SAMPLE_S))))
    # eps = (-w_y, w_x): w = eps x e_z
    M = np.array([[0.0, -1.0], [1.0, 0.0]])
    tilt = M @ x[2:4]
    C = M @ (cov[2:4, 2:4] + mean_var) @ M.T
    yaw = (-x[n_gyro], float(np.sqrt(max(cov[n_gyro, n_gyro], 0.0)))) if len(x) > n_gyro else (np.nan, np.nan)
    C3 = None
    if len(x) > n_gyro:  # eps and the correction's rotation about z (-yaw: eps's sign) together
        T = np.zeros((3, len(x)))
        T[:2, 2:4], T[2, n_gyro] = M, 1.0
        C3 = T @ cov @ T.T
        C3[:2, :2] += M @ mean_var @ M.T
    return PlanarTilt(tilt_rad=tilt, covariance_rad2=C, sigma_rad=np.sqrt(np.clip(np.diag(C), 0, None)),
                      heading_spread_rad=spread, rms_sway_rad=rms, samples=len(t), notes=(), yaw_rad=float(yaw[0]),
                      yaw_sigma_rad=yaw[1], covariance3_rad2=C3, rms_accel_mps2=rms_a)


def _smooth(x: np.ndarray) -> np.ndarray:
    """Triangle average over +-``SMOOTH_S`` along the first axis (samples ``SAMPLE_S`` apart)."""
    m = int(round(SMOOTH_S / SAMPLE_S))
    k = np.concatenate([np.arange(1, m + 1), np.arange(m + 1, 0, -1)]).astype(float)
    k /= k.sum()
    pad = np.concatenate([np.repeat(x[:1], m, axis=0), x, np.repeat(x[-1:], m, axis=0)])
    return np.stack([np.convolve(pad[:, j], k, "valid") for j in range(x.shape[1])], axis=1)


def _box_means(x: np.ndarray, ts: np.ndarray, t: np.ndarray) -> np.ndarray:
    """Mean of samples ``x`` (at ``ts``) within +-SAMPLE_S/2 of each ``t``; interpolated where none fall."""
    k0, k1 = np.searchsorted(ts, t - SAMPLE_S / 2), np.searchsorted(ts, t + SAMPLE_S / 2)
    c = np.concatenate([np.zeros((1, x.shape[1])), np.cumsum(x, axis=0)])
    n = (k1 - k0)[:, None]
    interp = np.stack([np.interp(t, ts, x[:, j]) for j in range(x.shape[1])], axis=1)
    return np.where(n > 0, (c[k1] - c[k0]) / np.maximum(n, 1), interp)


def _wheel_accel(t, tw, wheels) -> np.ndarray:
    """The wheels' (forward, centripetal) accelerations at ``t``, as ``_accel_sway`` reads them."""
    v, w = np.asarray(wheels[1], float), np.asarray(wheels[2], float)
    vw = _box_means(np.column_stack([v, v * w]), tw, t)
    return np.column_stack([_smooth(np.gradient(vw[:, :1], SAMPLE_S, axis=0))[:, 0], _smooth(vw[:, 1:])[:, 0]])


def _accel_sway(t, ti, h, tw, wheels) -> tuple[np.ndarray, list[np.ndarray]]:
    """The horizontal up the accelerometer shows at ``t`` ((specific force - the wheels' acceleration) / g, in
    the base frame so far), and the columns of what it is not sure of: a yaw of the mounting (turning the
    specific force), the lever arm's centripetal and tangential terms and the IMU's clock against the wheels'."""
    v, w = np.asarray(wheels[1], float), np.asarray(wheels[2], float)
    hb = _smooth(_box_means(h[:, :2], ti, t))
    vw = _box_means(np.column_stack([v, w, v * w, w * w]), tw, t)
    a_fwd = _smooth(np.gradient(vw[:, :1], SAMPLE_S, axis=0))[:, 0]
    dw = _smooth(np.gradient(vw[:, 1:2], SAMPLE_S, axis=0))[:, 0]
    sm = _smooth(vw[:, 2:])
    a_lat, w2 = sm[:, 0], sm[:, 1]
    up = (hb - np.column_stack([a_fwd, a_lat])) / GRAVITY_MPS2
    yaw = np.column_stack([-hb[:, 1], hb[:, 0]]) / GRAVITY_MPS2  # d up / d yaw of the mounting
    rx = -np.column_stack([-w2, dw]) / GRAVITY_MPS2  # the lever arm adds (-w^2 r_x - dw r_y, dw r_x - w^2 r_y)
    ry = -np.column_stack([-dw, -w2]) / GRAVITY_MPS2
    shift = -np.gradient(hb, SAMPLE_S, axis=0) / GRAVITY_MPS2  # the IMU's clock later by one second (linearised)
    return up, [yaw, rx, ry, shift]
