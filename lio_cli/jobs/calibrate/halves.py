"""The gyro's mounting rotation from each half of the final trajectory: their disagreement joins its 1-sigma.

The hand-eye fit's 1-sigma counts the residuals' correlation over neighbouring windows, not over seconds: a
robot turning about its vertical shows its roll and pitch only through the gyro's small horizontal increments,
which a slowly walking gyro bias (or anything else that follows the turns for seconds) leans on. A simulated
robot's roll and pitch came out 0.035 and 0.055 deg off at 1-sigma 0.010 and 0.013 (3.6 and 4.1 sigma); the two
halves of its log, each fitted alone, were 0.096 and 0.051 deg apart.
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from ...core.calibration import estimate_rotation
from ...errors import InputError
from ...geometry import so3_log
from ...model.records import ImuBatch
from .estimate import Estimates
from .passes import LidarTrajectory
from .report import MAX_ROTATION_SIGMA_RAD, rotation_cov_lidar, rotation_observable

MIN_SCANS = 60  # per half


def halves_spread(traj: LidarTrajectory, imu: ImuBatch, est: Estimates) -> None:
    """Add half the difference between the two halves' mountings (per LiDAR axis, squared) to the rotation's
    covariance, and to the lever arm's refined one; an axis this puts beyond ``MAX_ROTATION_SIGMA_RAD`` is no
    longer estimated (a skipped item says why). Nothing when a half is too short to fit on its own."""
    if est.rotation is None or est.offset is None or len(traj.stamps_ns) < 2 * MIN_SCANS:
        return
    s, P, n = traj.stamps_ns, traj.T_world_lidar, len(traj.stamps_ns)
    R = []
    for sel in (slice(0, n // 2), slice(n // 2, n)):
        try:
            R.append(estimate_rotation(s[sel], P[sel], imu.stamps_ns, imu.gyro_radps,
                                       imu_time_offset_s=est.offset.imu_time_offset_s,
                                       gyro_bias_radps=est.rotation.gyro_bias_radps).R_lidar_imu)
        except InputError:
            return
    apart = so3_log(R[1] @ R[0].T)
    extra = np.diag((apart / 2) ** 2)
    before = rotation_observable(est)
    rot = est.rotation
    cov = rot.covariance_rad2 + extra
    sig = np.sqrt(np.clip(np.diag(cov), 0, None))
    est.rotation = replace(rot, covariance_rad2=cov, sigma_rad=sig, observable=rot.observable & (sig <= MAX_ROTATION_SIGMA_RAD))
    lev = est.lever
    if lev is not None and np.isfinite(lev.rotation_covariance_rad2).all():
        lc = lev.rotation_covariance_rad2 + extra
        est.lever = replace(lev, rotation_covariance_rad2=lc, rotation_sigma_rad=np.sqrt(np.clip(np.diag(lc), 0, None)))
    for k in np.flatnonzero(before & ~rotation_observable(est)):  # now known worse than an estimated axis may be
        sk = np.degrees(np.sqrt(rotation_cov_lidar(est)[k, k]))
        est.skip(f"rotation_{'xyz'[k]}", f"the mounting's rotation about the LiDAR {'xyz'[k]} axis",
                 f"the two halves of the log put it {abs(np.degrees(apart[k])):.2f} deg apart (1-sigma {sk:.2f} deg "
                 "with that): record longer, or turn the platform about the other axes too")
