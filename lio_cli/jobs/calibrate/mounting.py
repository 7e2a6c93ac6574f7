"""One way for a step to turn the mounting it measured about some axes and take over its covariance there
(the rest's tilt and yaw, the wheels' yaw): the rotation and its lever-arm refinement turned alike, the axes it
makes estimated out of the skipped items, the precision notes said of the mounting before dropped."""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from ...geometry import so3_exp
from .estimate import Estimates
from .report import MAX_ROTATION_SIGMA_RAD, T_lidar_imu_of, rotation_observable


def turn_mounting(est: Estimates, T_ref, B: np.ndarray, z: np.ndarray, S: np.ndarray) -> None:
    """Turn the mounting by ``B^T z`` (rows of ``B``: LiDAR axes, orthonormal) and make its covariance about
    those axes ``S``, their correlations with the others gone."""
    before = rotation_observable(est)
    R = so3_exp(B.T @ z) @ T_lidar_imu_of(est, T_ref)[:3, :3]
    P = np.eye(3) - B.T @ B

    def fixed(c: np.ndarray) -> np.ndarray:
        return P @ c @ P + B.T @ S @ B

    def sigma(c: np.ndarray) -> np.ndarray:
        return np.sqrt(np.clip(np.diag(c), 0, None))

    rc = fixed(est.rotation.covariance_rad2)
    est.rotation = replace(est.rotation, R_lidar_imu=R, covariance_rad2=rc, sigma_rad=sigma(rc),
                           observable=sigma(rc) <= MAX_ROTATION_SIGMA_RAD)
    if est.lever is not None:
        lev = est.lever
        if np.isfinite(lev.rotation_covariance_rad2).all():
            lc = fixed(lev.rotation_covariance_rad2)
            est.lever = replace(lev, R_lidar_imu=R, rotation_covariance_rad2=lc, rotation_sigma_rad=sigma(lc))
        else:
            est.lever = replace(lev, R_lidar_imu=R)
    now = rotation_observable(est)
    gained = {f"rotation_{'xyz'[k]}" for k in np.flatnonzero(now & ~before)}
    if now.all():
        gained |= {s.key for s in est.skipped if s.key.startswith("rotation_about_") or s.key == "rotation"}
    est.skipped = [s for s in est.skipped if s.key not in gained]
    # the precision notes said of the mounting before (``report.imprecision_notes``) no longer hold
    est.notes = [x for x in est.notes if not (x.startswith("the mounting's rotation about the LiDAR") and
                                              "axis is measured to" in x)]
