"""A scan's initial guess and de-skew knots: the IMU state, the gyro (LiDAR-only scans), constant velocity, the
wheels, or the last pose."""

from __future__ import annotations

import numpy as np

from ...geometry import inv_pose
from ..imu import NavState, propagate
from ..motion_compensation import constant_velocity_knots
from .pose_checks import scale_delta
from .state import OdomState, Track
from .tuning import WHEEL_DELTA_LEAD_NS
from .wheel import wheel_delta


def guess(o: OdomState, t_prev: int, t_ref: int) -> np.ndarray:
    """The registration's initial guess of an IMU-primed scan, by the configured prior."""
    prior, track = o.cfg.prior, o.track
    if prior == "imu":
        return o.nav.state.pose()
    if prior == "constant-velocity":
        return track.last_pose @ track.last_delta
    if prior == "wheel":
        return track.last_pose @ wheel_delta(o.wheel, t_prev, t_ref, WHEEL_DELTA_LEAD_NS, track.last_delta)
    return track.last_pose.copy()


def cv_knots(deskew: str, track: Track, guess_pose: np.ndarray, t_prev: int, t_ref: int) -> tuple:
    """(knots, knot poses) de-skewing a scan by constant velocity from the last pose to ``guess_pose``; (None, None)
    with ``deskew: none``."""
    if deskew == "none":
        return None, None
    knots, rel = constant_velocity_knots(inv_pose(track.last_pose) @ guess_pose, t_prev, t_ref)
    return knots, track.last_pose[None] @ rel


def lidar_prior(o: OdomState, t_prev: int, t_ref: int, imu_gap: bool = False):
    """(guess, deskew knots, knot poses, gyro-primed) of a LiDAR-only scan: gyro rotation when the IMU can give it
    (it covers the interval without ``imu_gap``), else the configured prior."""
    track, prior = o.track, o.cfg.prior
    dt = (t_ref - t_prev) * 1e-9
    if o.imu_ready() and o.imu.until_ns() >= t_ref and not imu_gap:
        v = np.zeros(3)  # world velocity of the last inter-scan motion: p_last - p_prev over its duration
        if track.last_dt_s > 0:
            v = track.last_pose[:3, :3] @ track.last_delta[:3, :3].T @ track.last_delta[:3, 3] / track.last_dt_s
        bias = o.settings.bias_prior[0]
        bg = np.zeros(3) if bias is None else np.asarray(bias, dtype=np.float64)
        ba = np.zeros(3)
        s0 = NavState(t_prev, track.last_pose[:3, :3].copy(), track.last_pose[:3, 3].copy(), v, bg, ba)
        prop = propagate(s0, o.imu_window(t_prev), t_ref, o.ext, accel=False, planar=o.settings.planar)
        guess_pose = prop.poses[-1]
        if prior == "wheel":
            guess_pose = track.last_pose @ wheel_delta(o.wheel, t_prev, t_ref, WHEEL_DELTA_LEAD_NS, track.last_delta)
        knots = (prop.stamps_ns, prop.poses) if o.settings.deskew != "none" else (None, None)
        return guess_pose, knots[0], knots[1], True
    cv = track.last_delta if track.last_dt_s <= 0 else scale_delta(track.last_delta, dt / track.last_dt_s)
    guess_pose = track.last_pose @ (wheel_delta(o.wheel, t_prev, t_ref, WHEEL_DELTA_LEAD_NS, track.last_delta)
                                    if prior == "wheel" else np.eye(4) if prior == "none" else cv)
    return (guess_pose, *cv_knots(o.settings.deskew, track, guess_pose, t_prev, t_ref), False)
