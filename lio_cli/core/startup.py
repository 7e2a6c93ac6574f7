"""Start-up: gravity direction and gyro bias from a standing start, or a moving start.

At rest the accelerometer reads the specific force ``-R_i_w g``: its direction is "up" in the IMU frame, so
gravity fixes roll and pitch (yaw is free: the world frame starts at yaw zero), and the mean gyro reading is
its bias.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..geometry import so3_exp
from ..model.records import ImuBatch
from .imu import GRAVITY_MPS2


@dataclass
class StartUp:
    """How the state was initialised."""

    static: bool
    R_world_base: np.ndarray
    gyro_bias: np.ndarray
    samples: int
    reason: str


def gravity_aligned_rotation(f_base: np.ndarray) -> np.ndarray:
    """R_world_base whose world z is 'up' as the specific force ``f_base`` (at rest) says; yaw zero."""
    up = f_base / np.linalg.norm(f_base)
    z = np.array([0.0, 0.0, 1.0])
    axis = np.cross(up, z)
    s, c = np.linalg.norm(axis), float(up @ z)
    if s < 1e-12:
        return np.eye(3) if c > 0 else np.diag([1.0, -1.0, -1.0])
    R = so3_exp(axis / s * np.arctan2(s, c))  # rotates up (base) onto world z
    yaw = np.arctan2(R[1, 0], R[0, 0])
    Rz = so3_exp(np.array([0.0, 0.0, -yaw]))
    return Rz @ R


def start_up(imu: ImuBatch, R_base_imu: np.ndarray, window_ns: int, gravity_mps2: float = GRAVITY_MPS2,
             gyro_still_radps: float = 0.05, accel_still_mps2: float = 0.3,
             accel_bias: np.ndarray | None = None) -> StartUp:
    """Estimate gravity direction and gyro bias from a standing start, or fall back to a moving start.

    At rest a horizontal accelerometer bias is indistinguishable from tilt; pass ``accel_bias`` when it is
    known (a calibration) so the gravity direction is taken from the bias-free specific force.
    """
    ba = np.zeros(3) if accel_bias is None else np.asarray(accel_bias, dtype=np.float64)
    if len(imu) == 0:
        return StartUp(False, np.eye(3), np.zeros(3), 0, "no IMU data before the first scan: level start assumed")
    for win in (window_ns, window_ns // 2, window_ns // 4):  # the longest still stretch at the start
        sel = imu.stamps_ns <= imu.stamps_ns[0] + win
        gyro, accel = imu.gyro_radps[sel], imu.accel_mps2[sel]
        n = int(sel.sum())
        f_base = R_base_imu @ (accel.mean(axis=0) - ba)
        gyro_dev = float(np.linalg.norm(gyro - gyro.mean(axis=0), axis=1).max())
        accel_dev = float(np.abs(np.linalg.norm(accel - ba, axis=1) - gravity_mps2).max())
        R = gravity_aligned_rotation(f_base)
        if n >= 10 and gyro_dev < gyro_still_radps and accel_dev < accel_still_mps2:
            return StartUp(True, R, gyro.mean(axis=0), n,
                           f"standing start: gravity and gyro bias from {n} IMU samples over {win * 1e-9:.2f} s")
    return StartUp(False, R, np.zeros(3), n,
                   f"moving start (gyro spread {gyro_dev:.3f} rad/s, accel spread {accel_dev:.2f} m/s^2): "
                   "gravity from mean specific force, gyro bias zero")
