"""The first state of a fusion run: attitude, velocity, gyro bias, and how they were found.

Attitude: the IMU's own orientation where it is used (then the world's yaw is the IMU's, as in
robot_localization), else roll and pitch from gravity (yaw zero), else those of the first odometry pose.
A standing start (gyro and accelerometer still over the first window) also gives the gyro bias and a
velocity known to be zero, and gravity is the mean specific force. A moving start's specific force holds the
motion's accelerations too: gravity and the velocity then come from the IMU aligned with the odometry poses or
the wheels (``start_gravity``); the first wheel velocity, when there is one, is taken as measured.
"""

from __future__ import annotations

import numpy as np

from ...geometry import gravity_aligned_rotation, so3_exp_one, yaw_of
from .start_gravity import gravity_from_motion
from .start_state import Start
from .timeline import Prepared

GYRO_STILL_RADPS = 0.05
MAX_GYRO_BIAS_RADPS = 0.05  # about 3 deg/s: more than any usable MEMS gyro's bias
ACCEL_STILL_MPS2 = 0.3
STANDING_VELOCITY_SIGMA_MPS = 0.02


STILL_SPEED_MPS = 0.05  # wheel speed, or odometry displacement over the window per second, of a base at rest
GPS_SPEED_SIGMAS = 4.0  # the fixes' speed over the start window, in sigmas of its line fit, that says it moves
# and at least this: a receiver's step at rest (an RTK fix regained) reads as a slow motion over the window, and a
# slow start taken as standing costs little where a cruising one taken so diverged
GPS_MIN_SPEED_MPS = 0.5


def imu_quiet(w: np.ndarray, f: np.ndarray, gravity_mps2: float):
    """Whether IMU samples (..., n, 3: base rate, specific force) read as at rest, with the gyro's and the
    accelerometer's largest deviation; a steady turn looks like a gyro bias, so a "bias" above
    ``MAX_GYRO_BIAS_RADPS`` is taken as motion. Arrays over the leading axes (``rest``'s windows)."""
    w_mean = w.mean(axis=-2)
    gyro_dev = np.linalg.norm(w - w_mean[..., None, :], axis=-1).max(axis=-1)
    acc_dev = np.abs(np.linalg.norm(f, axis=-1) - gravity_mps2).max(axis=-1)
    quiet = (gyro_dev < GYRO_STILL_RADPS) & (acc_dev < ACCEL_STILL_MPS2) \
        & (np.linalg.norm(w_mean, axis=-1) < MAX_GYRO_BIAS_RADPS)
    return quiet, gyro_dev, acc_dev


def _moving_by_other_sources(prep: Prepared, t0: int, window_ns: int) -> str | None:
    """Why the wheels or the odometry say the base moves during the start window, or None."""
    w = prep.wheel
    if w is not None and len(w):
        sel = (w.stamps_ns >= t0) & (w.stamps_ns <= t0 + window_ns)
        speed = np.abs(np.nan_to_num(w.velocity_mps[sel, 0]))
        if len(speed) and float(np.median(speed)) > STILL_SPEED_MPS:
            return f"the wheels report {float(np.median(speed)):.2f} m/s"
    od = prep.odom
    if od is not None and len(od) > 1:
        sel = np.flatnonzero((od.stamps_ns >= t0) & (od.stamps_ns <= t0 + window_ns))
        if len(sel) > 1:
            dt_s = (od.stamps_ns[sel[-1]] - od.stamps_ns[sel[0]]) * 1e-9
            d = float(np.linalg.norm(od.poses[sel[-1], :3, 3] - od.poses[sel[0], :3, 3]))
            if dt_s > 0 and d / dt_s > STILL_SPEED_MPS:
                return f"the odometry moves {d / dt_s:.2f} m/s"
    if "gps" in prep.use and prep.gps is not None and len(prep.gps):
        return _moving_by_fixes(prep.gps, t0, window_ns)
    return None


def _moving_by_fixes(g, t0: int, window_ns: int) -> str | None:
    """Why the accepted fixes over the start window (the one the IMU was judged still over) say the base moves:
    their speed by a line fit beyond ``GPS_MIN_SPEED_MPS`` and ``GPS_SPEED_SIGMAS`` of its sigma (from the claimed
    sigma; from the scatter about the line where larger, its threshold then as rare under Student's law); None with
    fewer than 4 fixes there or where they scatter about the line over twice their claim (a step, not a motion)."""
    ok = np.flatnonzero(np.asarray(g.accepted, bool) & (g.stamps_ns >= t0) & (g.stamps_ns <= t0 + window_ns))
    if len(ok) < 4:
        return None
    t = (g.stamps_ns[ok] - g.stamps_ns[ok[0]]) * 1e-9
    sxx = float(np.sum((t - t.mean()) ** 2))
    if sxx <= 0:
        return None
    A = np.column_stack([np.ones(len(t)), t - t.mean()])
    xy = g.position_enu_m[ok, :2]
    coef, *_ = np.linalg.lstsq(A, xy, rcond=None)
    dof = 2 * (len(t) - 2)
    scatter = float(np.sqrt(np.sum((xy - A @ coef) ** 2) / dof))
    claim = float(np.median(g.sigma_h_m[ok]))
    if scatter > 2.0 * claim:
        return None
    k = GPS_SPEED_SIGMAS
    if scatter > claim:  # speed^2 sxx / scatter^2 is 2 F(2, dof): the same tail as 4 sigmas of a known one
        k = float(np.sqrt(dof * (np.exp(GPS_SPEED_SIGMAS**2 / dof) - 1.0)))
    speed = float(np.hypot(*coef[1]))
    if speed > max(GPS_MIN_SPEED_MPS, k * max(claim, scatter) / np.sqrt(sxx)):
        return f"the GPS fixes move {speed:.2f} m/s"
    return None


def _level(prep: Prepared, t0: int, window_ns: int, gravity_mps2: float, standing: bool, R: np.ndarray,
           why: list[str]) -> tuple[np.ndarray, np.ndarray | None]:
    """Roll and pitch from gravity, and the base-frame velocity where that finds it: at a standing start the
    mean specific force over the window; at a moving start the IMU aligned with the odometry or the wheels
    (``start_gravity``), which tell gravity from the motion's accelerations; the mean over the window's first
    fifth only when nothing can, and then said."""
    found = None
    if not standing:
        found = gravity_from_motion(prep, t0, window_ns, gravity_mps2)
        if found is not None and found.aligned:
            why.append(f"roll, pitch and velocity aligned with the {found.source} over {found.poses} poses")
            return gravity_aligned_rotation(found.up_base), found.v_base
    imu = prep.imu
    near = (imu.stamps_ns >= t0) & (imu.stamps_ns <= t0 + (window_ns if standing else window_ns // 5))
    f_mean = prep.imu_f_b[near].mean(axis=0) if near.any() else prep.imu_f_b[0]
    if np.linalg.norm(f_mean) <= 0.5 * gravity_mps2:
        return R, None
    if standing:
        why.append("roll and pitch from gravity")
    else:
        lacks = ("no odometry or wheels cover the start" if found is None else
                 f"the {found.source} over {found.poses} poses could not tell gravity from acceleration")
        why.append(f"roll and pitch from the mean specific force over {window_ns // 5 / 1e9:.2f} s, tilted by "
                   f"whatever the motion accelerated ({lacks})")
    return gravity_aligned_rotation(f_mean), None


def without_yaw(R: np.ndarray) -> np.ndarray:
    return so3_exp_one(np.array([0.0, 0.0, -float(yaw_of(R))])) @ R


def initial_state(prep: Prepared, window_ns: int, gravity_mps2: float, noise) -> Start:
    t0 = prep.t0_ns
    R = np.eye(3)
    yaw_from, why = "start", []
    bg, standing, v_base = np.zeros(3), False, None
    imu_use = prep.use.get("imu", set())
    imu = prep.imu
    if imu is not None and prep.imu_R_wb is not None:
        ok = np.flatnonzero(imu.orientation_valid & (imu.stamps_ns >= t0))
        if len(ok):
            R, yaw_from = prep.imu_R_wb[ok[0]].copy(), "imu_orientation"
            why.append("attitude from the IMU's orientation")
    if imu is not None and "gyro" in imu_use:
        sel = (imu.stamps_ns >= t0) & (imu.stamps_ns <= t0 + window_ns)
        # stillness is judged on what the sensor measured: the lever-arm terms that move its readings to the
        # base vanish at rest, and the angular acceleration in them only adds the gyro's noise (lever.py)
        w, f_imu = prep.imu_w_b[sel], imu.accel_mps2[sel]
        if len(w) >= 10:
            quiet, gyro_dev, acc_dev = imu_quiet(w, f_imu, gravity_mps2)
            standing = bool(quiet)
            moving = _moving_by_other_sources(prep, t0, window_ns) if standing else None
            if moving:  # at constant velocity an IMU reads exactly as at rest: the wheels or odometry tell
                standing = False
                why.append(f"moving start at constant velocity ({moving}; the IMU alone looks still)")
            elif standing:
                bg = w.mean(axis=0)
                why.append(f"standing start: gyro bias and zero velocity from {len(w)} samples")
            else:
                why.append(f"moving start (gyro spread {gyro_dev:.3f} rad/s, accel spread {acc_dev:.2f} m/s^2)")
        if yaw_from == "start" and "accel" in imu_use:
            R, v_base = _level(prep, t0, window_ns, gravity_mps2, standing, R, why)
    elif yaw_from == "start" and prep.odom is not None and len(prep.odom):
        R = without_yaw(prep.odom.poses[0, :3, :3])
        why.append("roll and pitch of the first odometry pose")
    v = np.zeros(3) if v_base is None else R @ v_base
    v_sigma = STANDING_VELOCITY_SIGMA_MPS if standing else noise.init_velocity_sigma_mps
    if not standing and prep.wheel is not None and len(prep.wheel):
        k = int(np.searchsorted(prep.wheel.stamps_ns, t0))
        if k < len(prep.wheel) and prep.wheel.stamps_ns[k] - t0 < window_ns:
            v = R @ np.nan_to_num(prep.wheel.velocity_mps[k])
            why.append("velocity from the first wheel message")
    bg_sigma = min(noise.init_gyro_bias_sigma_radps, 0.002) if standing else noise.init_gyro_bias_sigma_radps
    return Start(R, v, bg, v_sigma, bg_sigma, standing, yaw_from, "; ".join(why) or "level start at rest assumed")
