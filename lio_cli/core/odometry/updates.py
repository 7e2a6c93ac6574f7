"""Corrections of the IMU state: by the registered pose (EKF or complementary filter), by the wheel speed, and
the IMU clock shifted by what the online clock tracker finds."""

from __future__ import annotations

import numpy as np

from ...config.odom import FusionConfig
from ...model.records import OdometryRecord
from ..imu import NavState, flatten_planar
from .filter import (complementary_update, complementary_velocity_update, ekf_body_velocity_update, ekf_pose_update,
                     position_noise)
from .state import OdomState, OdomStats
from .tuning import MOVING_MPS, WHEEL_UPDATE_TAIL_NS
from .wheel import mean_twist


def correct(state: NavState, measured: np.ndarray, dirs_b: list[np.ndarray], dt_s: float, fc: FusionConfig,
            R_base_imu: np.ndarray, planar: bool) -> np.ndarray:
    """Correct ``state`` in place by the registered pose ``measured``; return the corrected pose."""
    dirs_w = [state.R @ d for d in dirs_b]
    if fc.method == "ekf":
        cov = position_noise(fc.position_sigma_m, dirs_w, fc.degenerate_sigma_m)
        ekf_pose_update(state, measured, fc.rotation_sigma_rad, cov)
    else:
        complementary_update(state, measured, fc.alpha, dt_s, R_base_imu, dirs_w)
    if planar:
        flatten_planar(state)
    return state.pose()


def wheel_update(state: NavState, records: list[OdometryRecord], t0: int, t1: int, fc: FusionConfig,
                 stats: OdomStats) -> None:
    """Wheel speed over the scan (forward, no side slip) corrects the predicted velocity in place."""
    if not records:
        return
    twist = mean_twist(records, t0, t1 + WHEEL_UPDATE_TAIL_NS)
    if twist is None:
        return
    if twist == (0.0, 0.0) and np.linalg.norm(state.v) > MOVING_MPS:
        stats.wheel_zero_skipped += 1  # an all-zero twist while moving: a pose source, not wheels
        return
    v_body = np.array([twist[0], 0.0, 0.0])
    if fc.method == "ekf":
        s = fc.wheel_speed_sigma_mps
        ekf_body_velocity_update(state, v_body, np.array([s, 2 * s, 2 * s]))
    else:
        complementary_velocity_update(state, v_body, fc.wheel_beta)
    stats.wheel_updates += 1


def track_clock(o: OdomState, t_ref: int, measured: np.ndarray, doubted: bool = False) -> None:
    """Give the clock tracker a registered pose; apply the offset it proposes to every IMU sample."""
    clock = o.clock
    if clock is None or clock.done:
        return
    clock.add_pose(t_ref, measured @ o.ext.T_base_lidar, doubted)
    delta = clock.propose(o.nav.state.bg, o.stats.scans)
    if delta:
        o.imu.shift(delta)
        o.event("clock offset", f"IMU stamps moved by {delta * 1e-6:+.2f} ms onto the LiDAR's clock "
                                f"(estimated online; {o.imu.shift_ns * 1e-6:+.2f} ms in all)")
