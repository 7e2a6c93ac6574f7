"""A ground vehicle's IMU mounting from a start at rest: roll and pitch from gravity against the ground the
LiDAR sees, the rotation about the vertical from the wheels' accelerations (speeding up, braking).

A car that drives off and mostly straight turns too little for hand-eye (one axis at best) and for the
planar-motion fit (its heading changes by degrees). At rest the accelerometer's up (gravity) and the ground's
normal in the LiDAR's scans (``core.calibration.lidar_ground``) are one vector seen in both frames; speeding up
and braking give a second, the forward direction: the IMU's specific force, its body sway taken out, against
the wheels' accelerations (``core.calibration.yaw_from_wheels``). The two pairs fix the whole rotation; each
replaces what hand-eye said about its axes where it is sharper.

Assumed: the ground under the vehicle at rest is level (a 1 % slope reads as 0.57 deg of roll or pitch). The
accelerometer's horizontal bias is indistinguishable from tilt on a vehicle turning about its vertical only:
``ACCEL_BIAS_PRIOR_MPS2`` per axis joins the 1-sigma.
"""

from __future__ import annotations

import numpy as np

from ...core.calibration.lidar_ground import fit_lidar_ground
from ...core.calibration.rotation import RotationCalib
from ...core.calibration.yaw_from_wheels import fit_wheel_sway_yaw
from ...errors import InputError
from ...geometry import axes_across, so3_exp
from ...model.records import ImuBatch
from .estimate import Estimates
from .mounting import turn_mounting
from .passes import SensorArrays
from .report import MAX_ROTATION_SIGMA_RAD, T_lidar_imu_of, rotation_cov_lidar, rotation_observable

ACCEL_BIAS_PRIOR_MPS2 = 0.04  # 1-sigma of the accelerometer's horizontal bias per axis (a MEMS IMU's)
GRAVITY_MPS2 = 9.81
REST_MARGIN_NS = 100_000_000  # a scan this far inside the still stretch (IMU clock) is taken as at rest
MAX_REST_SCANS = 10
HALF_MIN_ACCEL_MPS2 = 0.03  # a half log's fit: its braking and speeding up may be gentler
VERTICAL_COS = np.cos(np.radians(45.0))  # a LiDAR axis this close to the base z is the vertical one
SHARPER = 1.0  # a measurement replaces hand-eye's on a direction where its 1-sigma is below this times hand-eye's
OFFSET_SEARCH_S = 0.1  # an unmeasured clock offset is searched this far either side of the one so far...
OFFSET_STEP_S = 0.01  # ...on this grid, refined on a finer one (a fifth) about its best point
OFFSET_SIGMA_S = 0.005  # how far off the offset the wheels' accelerations line up at is taken to be


def rest_mounting(arrays: SensorArrays, imu: ImuBatch, T_base_lidar: np.ndarray | None, T_ref: np.ndarray | None,
                  est: Estimates) -> None:
    """Roll and pitch from gravity and the ground at rest, then the yaw from the wheels, each replacing
    hand-eye's axes where sharper (where hand-eye gave no rotation, the mounting starts from these alone);
    a note says what was used or why not."""
    if est.static is None or not arrays.first_scans:
        return
    Rbl = np.eye(3) if T_base_lidar is None else np.asarray(T_base_lidar, float)[:3, :3]
    wheels = arrays.has_wheels and est.wheel is not None
    if est.rotation is not None and not wheels:
        B = axes_across(Rbl[2])
        he = np.sqrt(np.clip(np.linalg.eigvalsh(B @ rotation_cov_lidar(est) @ B.T), 0, None))
        if (he <= SHARPER * ACCEL_BIAS_PRIOR_MPS2 / GRAVITY_MPS2).all():  # gravity cannot do better: no fit
            return
    a, b = est.static.start_ns + REST_MARGIN_NS, est.static.end_ns - REST_MARGIN_NS
    shift = 0 if est.offset is None else int(round(est.offset.imu_time_offset_s * 1e9))
    scans = [p for s, e, p in arrays.first_scans if s - shift >= a and e - shift <= b][:MAX_REST_SCANS]
    if not scans:
        return
    try:
        ground = fit_lidar_ground(np.concatenate(scans).astype(float), Rbl[2])
    except InputError as err:
        est.notes.append(f"roll and pitch from gravity and the ground at rest: {err}")
        return
    seeded = est.rotation is None
    if seeded:
        _seed(ground.normal, est)
    _tilt(ground, T_ref, est, len(scans), seeded)
    if wheels:
        _yaw(arrays, imu, Rbl, ground.normal, T_ref, est)
    if seeded:
        sigma_deg = np.degrees(rotation_cov_lidar(est).diagonal().clip(0) ** 0.5)
        for k in np.flatnonzero(~rotation_observable(est)):
            est.skip(f"rotation_{'xyz'[k]}", f"the mounting's rotation about the LiDAR {'xyz'[k]} axis",
                     _rest_reason(abs(Rbl[2, k]) > VERTICAL_COS, sigma_deg[k]))


def _rest_reason(vertical: bool, sigma_deg: float) -> str:
    """Why an axis stays unestimated when only the rest gave the mounting: about the vertical nothing at rest
    shows it; across it, gravity against the ground did not reach the estimator's threshold."""
    if vertical:
        return ("hand-eye could not use the rotations; gravity and the ground at rest give the roll and pitch, "
                "not the rotation about the vertical: speed up and brake (with wheel odometry) to show it")
    return (f"hand-eye could not use the rotations; gravity against the ground at rest gives it to 1-sigma "
            f"{sigma_deg:.2f} deg only (little or uneven ground in view): record at rest on open level ground, or turn "
            "the sensor about two axes for hand-eye")


def _seed(normal: np.ndarray, est: Estimates) -> None:
    """A mounting to start from where hand-eye gave none: the IMU's up on the ground's normal, any rotation
    about it (its covariance there unbounded, the rest replaced by ``_tilt``)."""
    up = est.static.up_imu
    ax = np.cross(up, normal)
    if np.linalg.norm(ax) < 1e-12:  # parallel, or upside down: any axis across
        ax = axes_across(up)[0] * 1e-12
    R = so3_exp(ax / np.linalg.norm(ax) * np.arctan2(np.linalg.norm(ax), float(up @ normal)))
    cov = np.eye(3) * np.pi**2
    est.rotation = RotationCalib(R_lidar_imu=R, sigma_rad=np.full(3, np.pi), covariance_rad2=cov,
                                 observable=np.zeros(3, bool), gyro_bias_radps=est.static.gyro_bias_radps,
                                 gyro_bias_sigma_radps=est.static.gyro_bias_sigma_radps, windows=0,
                                 rms_residual_rad=float("nan"), notes=(), registration_gain=np.zeros((3, 3)),
                                 fit_covariance_rad2=cov)
    est.skipped = [s for s in est.skipped if s.key != "rotation"]


def _tilt(ground, T_ref, est: Estimates, n_scans: int, seeded: bool) -> None:
    """Gravity's up onto the ground's normal: replaces hand-eye's tilt in the directions where it is sharper."""
    R = T_lidar_imu_of(est, T_ref)[:3, :3]
    n = ground.normal
    v = R @ est.static.up_imu
    ax = np.cross(v, n)
    c = ax / max(np.linalg.norm(ax), 1e-15) * np.arctan2(np.linalg.norm(ax), float(v @ n))  # turns v onto n
    B = axes_across(n)
    # gravity's direction: the accelerometer's noise (negligible at rest) and its horizontal bias
    S = B @ ground.covariance_rad2 @ B.T + np.eye(2) * (ACCEL_BIAS_PRIOR_MPS2 / GRAVITY_MPS2) ** 2
    lam, V = np.linalg.eigh(B @ rotation_cov_lidar(est) @ B.T)  # hand-eye's sharpest and vaguest tilt directions
    sig = np.sqrt(np.diag(V.T @ S @ V))
    he = np.sqrt(np.clip(lam, 0, None))
    vaguer = sig < SHARPER * he  # the directions where hand-eye is vaguer: those are replaced
    if not vaguer.any():
        est.notes.append(f"roll and pitch from gravity and the ground at rest (1-sigma {_deg(sig)} deg) left out: "
                         f"hand-eye's are sharper ({_deg(he)} deg)")
        return
    Vv = V[:, vaguer]
    turn_mounting(est, T_ref, Vv.T @ B, Vv.T @ B @ c, Vv.T @ S @ Vv)
    turned = "hand-eye gave no rotation" if seeded else f"{np.degrees(np.linalg.norm(c)):.2f} deg from hand-eye's" + \
        ("" if vaguer.all() else f" (one direction only: hand-eye's sharper across it, {np.degrees(he.min()):.2f} deg)")
    est.notes.append(f"the mounting's roll and pitch from gravity against the ground the LiDAR saw at rest ({n_scans} "
                     f"scans, {ground.inliers} ground points, {ground.height_m:.2f} m below, ground taken as level): "
                     f"{turned}, 1-sigma {_deg(sig)} deg (the "
                     f"accelerometer's horizontal bias, {ACCEL_BIAS_PRIOR_MPS2:g} m/s^2 assumed, looks like tilt)")


def _yaw(arrays: SensorArrays, imu: ImuBatch, Rbl: np.ndarray, up: np.ndarray, T_ref, est: Estimates) -> None:
    """The rotation about the base z from the wheels' accelerations (sway model), where sharper than so far;
    applied about ``up``, the vertical at rest (the base's z within its drawing's error), which keeps the roll
    and pitch just set and what was unknown about the vertical out of them."""
    u = up
    before = float(np.sqrt(max(u @ rotation_cov_lidar(est) @ u, 0.0)))
    w = est.wheel
    v, om = w.corrected(arrays.wheel_linear_mps, arrays.wheel_angular_radps)
    ws = arrays.wheel_stamps_ns
    R_base_imu = Rbl @ T_lidar_imu_of(est, T_ref)[:3, :3]
    bias = est.static.gyro_bias_radps  # measured at rest: a still start's best

    def fit(off: float, sel=None, isel=None, min_accel=None):
        sel = slice(None) if sel is None else sel
        isel = slice(None) if isel is None else isel
        kw = {} if min_accel is None else {"min_accel_mps2": min_accel}
        return fit_wheel_sway_yaw(ws[sel], v[sel], om[sel], imu.stamps_ns[isel], imu.accel_mps2[isel],
                                  imu.gyro_radps[isel], R_base_imu=R_base_imu, gyro_bias_radps=bias,
                                  imu_time_offset_s=off, exclude_ns=w.slip_ns, **kw)

    off0 = 0.0 if est.offset is None else est.offset.imu_time_offset_s
    measured = est.offset is not None and np.isfinite(est.offset.sigma_s)
    try:
        off, doff = (off0, est.offset.sigma_s) if measured else (_line_up(fit, off0), OFFSET_SIGMA_S)
        res = fit(off)
        slope = abs(_wrap(fit(off + doff).yaw_rad - fit(off - doff).yaw_rad)) / 2
    except InputError as err:
        est.notes.append(f"the mounting's rotation about the base z from speeding up and braking: {err}")
        return
    mid = int(np.median(ws))
    shift = int(round(off * 1e9))
    try:
        halves = [fit(off, ws < mid, imu.stamps_ns + shift < mid, HALF_MIN_ACCEL_MPS2).yaw_rad,
                  fit(off, ws >= mid, imu.stamps_ns + shift >= mid, HALF_MIN_ACCEL_MPS2).yaw_rad]
    except InputError as err:  # the whole log's fit stands; only the halves' check is missing
        est.notes.append(f"the wheels' yaw on the log's halves: {err} (their disagreement left out of the 1-sigma)")
        halves = [res.yaw_rad, res.yaw_rad]
    half = abs(_wrap(halves[1] - halves[0])) / 2
    sigma = float(np.sqrt(res.sigma_rad**2 + slope**2 + half**2))
    if sigma > MAX_ROTATION_SIGMA_RAD or sigma >= SHARPER * before:
        est.notes.append(f"the wheels' accelerations (body sway taken out) give the mounting's rotation about the base "
                         f"z to 1-sigma {np.degrees(sigma):.2f} deg: not used ({np.degrees(before):.2f} deg so far)")
        return
    # the yaw measured is the whole correction about u: R -> exp(yaw u) R
    turn_mounting(est, T_ref, u[None, :], np.array([res.yaw_rad]), np.array([[sigma**2]]))
    how = "the clock offset measured" if measured else \
        f"the clock offset where the two line up best, {1e3 * off:+.1f} ms (used for this only)"
    est.notes.append(f"the mounting's rotation about the base z from the wheels' accelerations (speeding up, braking; "
                     f"the body's sway taken out): {np.degrees(res.yaw_rad):+.2f} deg, 1-sigma {np.degrees(sigma):.2f} "
                     f"deg ({res.windows} windows, rms {res.rms_accel_mps2:.2f} m/s^2, halves "
                     f"{np.degrees(halves[0]):+.2f}/{np.degrees(halves[1]):+.2f} deg; {how})")


def _line_up(fit, off0: float) -> float:
    """The clock offset at which the wheels' and the IMU's accelerations agree best (least residual)."""
    def ss(off: float) -> float:
        return fit(off).rms_residual_mps2 ** 2

    grid = off0 + np.arange(-OFFSET_SEARCH_S, OFFSET_SEARCH_S + 1e-9, OFFSET_STEP_S)
    best = grid[int(np.argmin([ss(x) for x in grid]))]
    fine = best + np.arange(-1.0, 1.0 + 1e-9, 0.2) * OFFSET_STEP_S
    vals = np.array([ss(x) for x in fine])
    k = int(np.clip(np.argmin(vals), 1, len(fine) - 2))
    y0, y1, y2 = vals[k - 1:k + 2]
    den = y0 - 2 * y1 + y2
    step = fine[1] - fine[0]
    return float(fine[k] + (0.5 * (y0 - y2) / den * step if den > 0 else 0.0))


def _deg(v: np.ndarray) -> str:
    return "/".join(f"{np.degrees(x):.2f}" for x in v)


def _wrap(angle: float) -> float:
    """An angle difference in (-pi, pi]: two yaws either side of 180 deg are close."""
    return float(np.angle(np.exp(1j * angle)))

