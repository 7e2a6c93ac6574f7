"""IMU-primed scans the IMU state cannot explain: retried LiDAR-only (a failed registration) or placed LiDAR-only
with the state kept (a doubted scan); either may send the odometry back to LiDAR-only scans."""

from __future__ import annotations

import numpy as np

from ...model.records import PointCloud
from .guards import count_lost
from .lidar_step import lidar_step
from .pose_checks import lean_on_prior
from .scan import finish
from .state import OdomState, ScanResult
from .updates import track_clock


def failed_registration(o: OdomState, cloud: PointCloud, t_prev: int, t_ref: int, measured: np.ndarray,
                        guess: np.ndarray, dirs_b: list) -> ScanResult:
    """The prediction cannot explain the scan: if the LiDAR alone can, the state is suspect and starts again from
    LiDAR-only scans; if it cannot either, the scan is bad and the prediction stands."""
    o.stats.registration_failures += 1
    kept, g_world = o.nav.state, o.nav.g_world
    o.lose_imu_state()
    res = lidar_step(o, cloud, t_prev, t_ref, retry=True)
    if res is not None:
        o.stats.recoveries += 1
        o.event("recovery", "the IMU prediction could not explain the scan (registration "
                            f"{np.linalg.norm(measured[:3, 3] - guess[:3, 3]):.2f} m from it or without "
                            "correspondences), LiDAR-only registration could: back to LiDAR-only scans")
        return res
    o.nav.state, o.nav.g_world = kept, g_world
    count_lost(o.health, o.cfg.max_lost_scans, o.stats.scans, t_ref)
    return finish(o, t_ref, o.nav.state.pose(), None, None, dirs_b, True)


def doubted_scan(o: OdomState, cloud: PointCloud, t_prev: int, t_ref: int, measured: np.ndarray, guess: np.ndarray,
                 frame: np.ndarray, dirs_b: list, reason: str | None, points: np.ndarray | None = None) -> ScanResult:
    """A scan whose registration the IMU state cannot explain: its pose comes from LiDAR-only registration (gated
    around the gyro and the last poses, not around the doubted prediction); the state follows that pose and keeps
    its velocity, biases and gravity. ``reason``: several such scans in a row, which drop the state."""
    o.stats.doubted_scans += 1
    kept, g_world, doubt = o.nav.state, o.nav.g_world, o.health.doubt
    o.lose_imu_state(keep_clock=True)
    res = lidar_step(o, cloud, t_prev, t_ref, retry=True, window=False)
    o.nav.state, o.nav.g_world, o.health.doubt = kept, g_world, doubt
    if res is None:  # LiDAR-only failed: the prediction-gated registration is all there is
        pose = lean_on_prior(measured, guess, dirs_b)
        res = finish(o, t_ref, pose, frame, None, dirs_b, False, points)
    elif reason is None:
        # the LiDAR-only pose times the IMU clock as a registered one does, its window marked (see
        # clock_offset.APPLY_SIGMA_DOUBTED_S)
        track_clock(o, t_ref, res.pose, doubted=True)
    o.nav.state.R, o.nav.state.p = res.pose[:3, :3].copy(), res.pose[:3, 3].copy()
    if reason is not None:
        o.stats.recoveries += 1
        o.event("recovery", reason + ": back to LiDAR-only scans")
        o.lose_imu_state()
    return res
