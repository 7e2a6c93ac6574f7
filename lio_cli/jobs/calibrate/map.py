"""The map rounds of ``lio calibrate``: the last gyro-primed pass's poses re-registered point-to-plane against
one map of all its scans (``core.calibration.map_refine``), de-skewed through the estimates so far, and the
estimators run again after each round.

The rounds sharpen the roll and pitch that scan-to-local-map odometry scatters, which is what limits the mounting.
A round is kept only when it makes the LiDAR's rotations agree better with the gyro's. 2D scans have no roll or
pitch to sharpen and are left as the fused passes give them.
"""

from __future__ import annotations

import time

import numpy as np

from ...config.calibrate import CalibrateConfig
from ...core.calibration.map_refine import Sweep, refine_poses
from ...core.calibration.signals import GyroOrientation
from ...errors import InputError
from ...model.records import ImuBatch
from . import estimate as steps
from .passes import LidarTrajectory
from .report import T_lidar_imu_of

SWEEP_VOXEL = 0.6  # scans kept thinned to this share of the odometry's map voxel (0.3 m indoors)...
MAP_VOXEL = 0.4  # ...and the map's voxels this share of it
KEEP_BELOW = 0.9  # a round is kept when the hand-eye residual drops below this share of the one before
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
               times: dict[str, float]) -> tuple[LidarTrajectory, steps.Estimates]:
    """The final estimates on the last pass's ``traj``, then up to ``cfg.map_rounds`` rounds of map refinement,
    each followed by the final estimators again; returns the trajectory and estimates kept. ``est``: the
    estimates of the passes before (their notes carry on). A round is kept only when the LiDAR's rotations then
    agree better with the gyro's (the hand-eye residual below ``KEEP_BELOW`` of the best so far); else the
    rounds stop there. Every candidate is estimated alike (final), so a clock offset kept as given on one and
    estimated on another cannot decide."""
    t0 = time.perf_counter()
    best, best_est, kept = traj, est.trial(), 0
    steps.extrinsics(best, imu, cfg, best_est, where, T_ref, final=True, prior_offset=prior_offset)
    times["estimate_final"] = time.perf_counter() - t0
    if best_est.rotation is None:  # nothing to de-skew the rounds' scans with: the pass's poses are final
        return best, best_est
    # each scan is registered against a map holding it and its neighbours, so the rounds' pose errors are shared
    # and their residuals understate them: the values move, the 1-sigmas (and what is observable) stay the pass's
    floors = steps.floors_of(best_est)
    for k in range(1, cfg.map_rounds + 1):
        t0 = time.perf_counter()
        gyro = GyroOrientation(imu.stamps_ns, imu.gyro_radps, best_est.rotation.gyro_bias_radps)
        poses, moved = refine_poses(best.stamps_ns, best.T_world_lidar, sweeps, gyro,
                                    T_lidar_imu_of(best_est, T_ref)[:3, :3], best_est.offset.imu_time_offset_s,
                                    MAP_VOXEL * voxel_m)
        how = (f"; then {k} round{'s' if k > 1 else ''} against one map of all its scans (point-to-plane, {moved} "
               f"of {len(poses)} poses moved in the last)")
        trial_traj = LidarTrajectory(traj.stamps_ns, poses, traj.scans_used, traj.scans_total, traj.description + how)
        times[f"map_round_{k}"] = time.perf_counter() - t0
        t0 = time.perf_counter()
        trial = est.trial()
        try:
            steps.extrinsics(trial_traj, imu, cfg, trial, where, T_ref, final=True, prior_offset=prior_offset,
                             floors=floors)
            better = trial.rotation is not None and \
                trial.rotation.rms_residual_rad < KEEP_BELOW * best_est.rotation.rms_residual_rad
        except InputError:
            better = False
        times[f"estimate_map_{k}"] = time.perf_counter() - t0
        if not better:
            best_est.notes.append(f"map round {k} left out: the LiDAR's rotations agreed no better with the gyro's "
                                  f"after it (the poses are those of {f'round {kept}' if kept else 'the last pass'})")
            break
        best, best_est, kept = trial_traj, trial, k
    return best, best_est
