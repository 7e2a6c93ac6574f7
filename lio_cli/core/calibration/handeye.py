"""Hand-eye on rotation increments, shared by the time-offset and rotation estimators.

Over any interval the LiDAR's rotation increment and the IMU's are the same rotation seen from two frames:
``dR_lidar = R_lidar_imu dR_imu R_lidar_imu^T``, so their rotation vectors obey ``phi_lidar = R_lidar_imu
phi_imu`` exactly, however large the increment. ``phi_imu`` comes from the gyro (minus its bias, which turns
the increment by about ``-b dt``); ``phi_lidar`` from the LiDAR odometry trajectory.
"""

from __future__ import annotations

import numpy as np

from ...geometry import so3_log
from .signals import GyroOrientation

MAX_INCREMENT_RAD = 2.5  # near pi a rotation vector is ill-defined


def interval_pairs(stamps_ns: np.ndarray, span: int, gap_factor: float = 2.5) -> tuple[np.ndarray, np.ndarray]:
    """Index pairs (i, i + span) of trajectory stamps, leaving out intervals holding a gap (a step longer than
    ``gap_factor`` times the median step)."""
    d = np.diff(stamps_ns)
    gap = np.concatenate([[0], np.cumsum(d > gap_factor * np.median(d))])
    i = np.arange(len(stamps_ns) - span)
    keep = gap[i + span] == gap[i]
    return i[keep], i[keep] + span


def lidar_increments(poses: np.ndarray, ia: np.ndarray, ib: np.ndarray) -> np.ndarray:
    """Rotation vectors of R_a^T R_b (in the LiDAR frame at a) -> (n,3)."""
    R = poses[:, :3, :3]
    return so3_log(np.swapaxes(R[ia], 1, 2) @ R[ib])


def imu_increments(gyro: GyroOrientation, ta_ns: np.ndarray, tb_ns: np.ndarray, imu_time_offset_s: float) -> np.ndarray:
    """Rotation vectors of the gyro's increments over LiDAR-clock intervals [ta, tb] -> (n,3)."""
    return so3_log(gyro.increments(gyro.relative_s(ta_ns, imu_time_offset_s), gyro.relative_s(tb_ns, imu_time_offset_s)))


def kabsch(A: np.ndarray, B: np.ndarray, w: np.ndarray | None = None) -> np.ndarray:
    """Rotation R minimising sum w_i |A_i - R B_i|^2."""
    H = (B * (1.0 if w is None else w[:, None])).T @ A
    U, _, Vt = np.linalg.svd(H)
    D = np.diag([1.0, 1.0, np.sign(np.linalg.det(Vt.T @ U.T))])
    return Vt.T @ D @ U.T


def align(phi_lidar: np.ndarray, phi_imu: np.ndarray, dt_s: np.ndarray, w: np.ndarray | None = None,
          iterations: int = 4) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(R_lidar_imu, gyro bias correction b, residuals) with phi_lidar = R (phi_imu - b dt), by alternating
    Kabsch and the closed-form bias."""
    w = np.ones(len(dt_s)) if w is None else w
    b = np.zeros(3)
    for _ in range(iterations):
        R = kabsch(phi_lidar, phi_imu - b * dt_s[:, None], w)
        d = phi_imu - phi_lidar @ R  # = b dt + noise
        b = (w[:, None] * dt_s[:, None] * d).sum(axis=0) / (w * dt_s**2).sum()
    r = phi_lidar - (phi_imu - b * dt_s[:, None]) @ R.T
    return R, b, r


def keep_finite_increments(phi_lidar: np.ndarray) -> np.ndarray:
    """Mask of increments small enough for their rotation vectors to be well defined."""
    return np.linalg.norm(phi_lidar, axis=1) < MAX_INCREMENT_RAD
