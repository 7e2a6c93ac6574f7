"""A ground vehicle's mounting yaw from its wheels' accelerations, where the gyro and the LiDAR left it unknown.

A car or a ground robot turns about its vertical only, which hides the IMU's rotation about that axis from
hand-eye; the LiDAR trajectory's accelerations are too noisy to show it (registration follows the travel in
steps). The wheels measure the base's accelerations directly (``core.calibration.yaw_from_wheels``).
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from ...core.calibration.yaw_from_wheels import estimate_wheel_yaw
from ...errors import InputError
from ...model.records import ImuBatch
from .estimate import Estimates
from .passes import SensorArrays
from .mounting import turn_mounting
from .report import MAX_ROTATION_SIGMA_RAD, T_lidar_imu_of, rotation_cov_lidar


UNMEASURED_OFFSET_S = 0.04  # how far off a clock offset the motion could not measure is taken to be


def wheel_yaw(arrays: SensorArrays, imu: ImuBatch, T_base_lidar: np.ndarray | None, T_ref: np.ndarray | None,
              est: Estimates) -> None:
    """Turn ``est``'s mounting about the base z by what the wheels' accelerations show, when their 1-sigma is
    within ``MAX_ROTATION_SIGMA_RAD`` and below the mounting's there (the two are not joined: both read the same
    accelerations); the axes it makes estimated leave the skipped items."""
    if est.rotation is None or est.wheel is None or T_base_lidar is None or est.offset is None:
        return
    Rbl = np.asarray(T_base_lidar, float)[:3, :3]
    u = Rbl[2]  # the base z in the LiDAR frame
    cov = rotation_cov_lidar(est)
    current = np.sqrt(max(float(u @ cov @ u), 0.0))
    w = est.wheel
    R_lidar_imu = T_lidar_imu_of(est, T_ref)[:3, :3]
    R_base_imu = Rbl @ R_lidar_imu
    def fit(offset_s: float):
        return estimate_wheel_yaw(arrays.wheel_stamps_ns, *w.corrected(arrays.wheel_linear_mps, arrays.wheel_angular_radps),
                                  imu.stamps_ns, imu.accel_mps2, R_base_imu=R_base_imu, imu_time_offset_s=offset_s,
                                  exclude_ns=w.slip_ns, gyro_radps=imu.gyro_radps,
                                  gyro_bias_radps=est.rotation.gyro_bias_radps)

    off = est.offset.imu_time_offset_s
    # the wheels and the IMU are aligned through the clock offset: its uncertainty (one the motion could not
    # measure, given or assumed: UNMEASURED_OFFSET_S) moves the yaw, by the slope measured either side
    doff = est.offset.sigma_s if np.isfinite(est.offset.sigma_s) else UNMEASURED_OFFSET_S
    try:
        res = fit(off)
        if doff > 0:
            slope = abs(np.angle(np.exp(1j * (fit(off + doff).yaw_rad - fit(off - doff).yaw_rad)))) / 2
            res = replace(res, sigma_rad=float(np.hypot(res.sigma_rad, slope)))
    except InputError as err:
        if current > MAX_ROTATION_SIGMA_RAD:
            est.notes.append(f"the mounting's rotation about the base z axis: {err}")
        return
    if current <= MAX_ROTATION_SIGMA_RAD and res.sigma_rad >= current:
        return
    if res.sigma_rad > MAX_ROTATION_SIGMA_RAD:
        est.notes.append(f"the wheels' accelerations leave the mounting's rotation about the base z axis at 1-sigma "
                         f"{np.degrees(res.sigma_rad):.2f} deg: not estimated ({res.windows} windows, rms {res.rms_accel_mps2:.2f} "
                         f"m/s^2, residual {res.rms_residual_mps2:.3f}, scale {res.scale:.3f}; speed up, brake and turn harder)")
        return
    turn_mounting(est, T_ref, u[None, :], np.array([res.yaw_rad]), np.array([[res.sigma_rad**2]]))
    est.notes.append(f"the mounting's rotation about the base z axis from the wheels' accelerations: "
                     f"{np.degrees(res.yaw_rad):+.2f} deg from the gyro's, 1-sigma {np.degrees(res.sigma_rad):.2f} deg "
                     f"({res.windows} windows, rms {res.rms_accel_mps2:.2f} m/s^2)")
