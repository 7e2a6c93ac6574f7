"""A ground vehicle's IMU roll and pitch on its base from the planar-motion constraint, joined to what hand-eye
and the accelerations gave (``core.calibration.ground_plane``).

Hand-eye reads a car's roll and pitch from LiDAR rotations that follow only part of the body's sway; the gyro
alone, carried through a whole drive, shows them against the turns. The two are combined by their information
(the sharper one dominates: the gyro on a car, a fused 2D scanner's passes on a robot).
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from ...core.calibration.ground_plane import estimate_planar_tilt
from ...errors import InputError
from ...geometry import so3_exp
from ...model.records import ImuBatch
from .estimate import Estimates
from .report import MAX_ROTATION_SIGMA_RAD, T_lidar_imu_of, rotation_cov_lidar, rotation_observable


def planar_tilt(imu: ImuBatch, T_base_lidar: np.ndarray | None, T_ref: np.ndarray | None, est: Estimates,
                ground_vehicle: bool) -> None:
    """Join the planar-motion roll and pitch to ``est``'s mounting when the motion was planar (the vertical
    stays put in the base frame); ``ground_vehicle`` (it has wheels): say why when it could not."""
    if est.rotation is None or T_base_lidar is None:
        return
    Rbl = np.asarray(T_base_lidar, float)[:3, :3]
    R_lidar_imu = T_lidar_imu_of(est, T_ref)[:3, :3]
    try:
        res = estimate_planar_tilt(imu.stamps_ns, imu.gyro_radps, R_base_imu=Rbl @ R_lidar_imu,
                                   gyro_bias_radps=est.rotation.gyro_bias_radps)
    except InputError as err:
        if ground_vehicle:
            est.notes.append(f"the mounting's roll and pitch on the base: {err}")
        return
    if (res.sigma_rad > MAX_ROTATION_SIGMA_RAD).any():
        if ground_vehicle:
            est.notes.append(f"roll and pitch from planar motion: 1-sigma {_deg(res.sigma_rad)} deg, not used (the heading "
                             f"changed {np.degrees(res.heading_spread_rad):.0f} deg; turn both ways, 90 deg or more)")
        return
    before = rotation_observable(est)
    B = Rbl[:2]  # the base x and y axes in the LiDAR frame: B d = -eps for a correction exp(d) in the LiDAR frame
    Si = np.linalg.inv(res.covariance_rad2)
    info = np.linalg.inv(rotation_cov_lidar(est)) + B.T @ Si @ B
    cov = np.linalg.inv(info)
    d = cov @ (B.T @ Si @ -res.tilt_rad)
    R_new = so3_exp(d) @ R_lidar_imu
    sig = np.sqrt(np.clip(np.diag(cov), 0, None))
    rot = est.rotation
    est.rotation = replace(rot, R_lidar_imu=R_new, covariance_rad2=cov, sigma_rad=sig,
                           observable=sig <= MAX_ROTATION_SIGMA_RAD)
    if est.lever is not None:
        lev = est.lever
        refined = np.isfinite(lev.rotation_covariance_rad2).all()
        est.lever = replace(lev, R_lidar_imu=R_new, rotation_covariance_rad2=cov if refined else
                            lev.rotation_covariance_rad2, rotation_sigma_rad=sig if refined else lev.rotation_sigma_rad)
    now = rotation_observable(est)
    gained = {f"rotation_{'xyz'[k]}" for k in np.flatnonzero(now & ~before)}
    if now.all():
        gained |= {s.key for s in est.skipped if s.key.startswith("rotation_about_")}
    est.skipped = [s for s in est.skipped if s.key not in gained]
    est.notes.append(f"the mounting's roll and pitch on the base from planar motion (the gyro's turns about the base "
                     f"z): {_deg(-res.tilt_rad, signed=True)} deg from hand-eye's, 1-sigma {_deg(res.sigma_rad)} deg "
                     f"(heading changed {np.degrees(res.heading_spread_rad):.0f} deg, sway {np.degrees(res.rms_sway_rad):.2f} "
                     "deg rms); joined by their information")


def _deg(v: np.ndarray, signed: bool = False) -> str:
    return "/".join(f"{np.degrees(x):{'+' if signed else ''}.2f}" for x in v)
