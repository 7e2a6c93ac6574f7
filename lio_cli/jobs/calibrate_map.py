"""The map rounds of ``lio calibrate``: the last gyro-primed pass's poses re-registered point-to-plane against
one map of all its scans (``core.calibration.map_refine``), de-skewed through the estimates so far, and the
estimators run again after each round.

On a 16-beam handheld walk the odometry's roll and pitch scatter 0.4-0.5 deg per scan, and the mounting came out
0.24-0.61 deg off (ten simulated walks); after three rounds the scatter is about a third and the mounting within
0.12 deg. 2D scans have no roll or pitch to sharpen and are left as the fused passes give them.
"""

from __future__ import annotations

import time

import numpy as np

from ..config.calibrate import CalibrateConfig
from ..core.calibration.map_refine import Sweep, refine_poses
from ..core.calibration.signals import GyroOrientation
from ..model.records import ImuBatch
from . import calibrate_estimate as steps
from .calibrate_passes import LidarTrajectory
from .calibrate_report import T_lidar_imu_of

SWEEP_VOXEL = 0.6  # scans kept thinned to this share of the odometry's map voxel (0.3 m indoors)...
MAP_VOXEL = 0.4  # ...and the map's voxels this share of it
MAX_SWEEPS = 3000  # five minutes at 10 Hz: a longer log keeps the odometry's poses (memory, time)


def wanted(cfg: CalibrateConfig, planar: bool, scans: int, notes: list[str]) -> bool:
    """Whether the last pass should keep its scans for map rounds (a note says why not, when that is news)."""
    if cfg.map_rounds == 0 or cfg.refine_passes == 0 or planar:
        return False
    if scans > MAX_SWEEPS:
        notes.append(f"no map rounds: {scans} scans, more than {MAX_SWEEPS} (memory and time); the poses are the "
                     "odometry pass's, whose roll and pitch scatter more (a few minutes of motion calibrate best)")
        return False
    return True


def map_rounds(traj: LidarTrajectory, sweeps: dict[int, Sweep], voxel_m: float, imu: ImuBatch, cfg: CalibrateConfig,
               est: steps.Estimates, where: str, T_ref: np.ndarray | None, prior_offset: float | None,
               times: dict[str, float]) -> LidarTrajectory:
    """``cfg.map_rounds`` rounds of map refinement, each followed by the estimators (the last one final)."""
    poses, moved = traj.T_world_lidar, 0
    for k in range(1, cfg.map_rounds + 1):
        t0 = time.perf_counter()
        T_li = T_lidar_imu_of(est, T_ref)
        gyro = GyroOrientation(imu.stamps_ns, imu.gyro_radps, est.rotation.gyro_bias_radps)
        poses, moved = refine_poses(traj.stamps_ns, poses, sweeps, gyro, T_li[:3, :3], est.offset.imu_time_offset_s,
                                    MAP_VOXEL * voxel_m)
        traj = LidarTrajectory(traj.stamps_ns, poses, traj.scans_used, traj.scans_total, traj.description)
        times[f"map_round_{k}"] = time.perf_counter() - t0
        t0 = time.perf_counter()
        steps.extrinsics(traj, imu, cfg, est, where, T_ref, final=k == cfg.map_rounds, prior_offset=prior_offset)
        times[f"estimate_map_{k}"] = time.perf_counter() - t0
    how = (f"; then {cfg.map_rounds} rounds against one map of all its scans (point-to-plane, {moved} of "
           f"{len(traj.stamps_ns)} poses moved in the last)")
    return LidarTrajectory(traj.stamps_ns, poses, traj.scans_used, traj.scans_total, traj.description + how)
