"""A ground vehicle's lever arm in the base's x-y plane from its wheels, where the LiDAR left it unknown.

The LiDAR trajectory of a vehicle is too coarse in its accelerations to place the IMU (1-sigma 6-20 cm on every
simulated car and robot); the wheels' accelerations, fitted against the IMU's for the mounting's yaw
(``core.calibration.yaw_from_wheels``), show the lever arm's centripetal ``w^2 r`` and tangential ``dw/dt x r``
terms too: its x and y along the base, to millimetres on a simulated robot turning at 0.5 rad/s. The vertical
stays what the LiDAR's fit (or the prior) says: turns about the vertical do not show it.
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from ...core.calibration.yaw_from_wheels import MIN_ACCEL_MPS2, estimate_wheel_yaw, halves_scaled
from ...errors import InputError
from ...model.records import ImuBatch
from .estimate import Estimates
from .passes import SensorArrays
from .report import T_lidar_imu_of

MAX_SIGMA_M = 0.05  # the lever arm estimator's threshold of an observable axis
HALF_MIN_ACCEL_MPS2 = 0.03  # a half of a log that starts or pauses standing still holds less acceleration


def lever_from_wheels(arrays: SensorArrays, imu: ImuBatch, T_base_lidar: np.ndarray | None, T_ref: np.ndarray | None,
                      est: Estimates) -> None:
    """Replace ``est``'s lever arm along the LiDAR axes where the wheels' fit pins it better (base x, y; the base z
    kept), and drop the skipped items those axes leave."""
    if est.rotation is None or est.lever is None or est.wheel is None or T_base_lidar is None or est.offset is None:
        return
    Tbl = np.asarray(T_base_lidar, float)
    Rbl = Tbl[:3, :3]
    T_li = T_lidar_imu_of(est, T_ref)
    w = est.wheel
    ws = arrays.wheel_stamps_ns

    def fit(sel: np.ndarray, isel: np.ndarray, min_accel: float = MIN_ACCEL_MPS2):
        return estimate_wheel_yaw(ws[sel], *w.corrected(arrays.wheel_linear_mps[sel], arrays.wheel_angular_radps[sel]),
                                  imu.stamps_ns[isel], imu.accel_mps2[isel], R_base_imu=Rbl @ T_li[:3, :3],
                                  imu_time_offset_s=est.offset.imu_time_offset_s, exclude_ns=w.slip_ns,
                                  gyro_radps=imu.gyro_radps[isel], gyro_bias_radps=est.rotation.gyro_bias_radps,
                                  min_accel_mps2=min_accel)

    everything = np.ones(len(ws), bool), np.ones(len(imu.stamps_ns), bool)
    try:
        res = fit(*everything)
        # each half of the log alone (one may hold less acceleration: what it gives is only compared): their
        # disagreement joins the 1-sigma (the residuals' own understate it: docs/benchmarks.md)
        mid = int(np.median(ws))
        shift = int(round(est.offset.imu_time_offset_s * 1e9))
        halves = [fit(ws < mid, imu.stamps_ns + shift < mid, HALF_MIN_ACCEL_MPS2),
                  fit(ws >= mid, imu.stamps_ns + shift >= mid, HALF_MIN_ACCEL_MPS2)]
    except InputError as err:
        est.notes.append(f"the lever arm in the base plane: {err}")
        return
    res = replace(res, lever_cov_m2=halves_scaled(res.lever_cov_m2, *halves))
    sig_xy = np.sqrt(np.clip(np.diag(res.lever_cov_m2), 0, None))
    if not (sig_xy <= MAX_SIGMA_M).all():
        est.notes.append(f"the wheels' accelerations leave the lever arm in the base plane at 1-sigma "
                         f"{100 * sig_xy.max():.1f} cm: not estimated from them (turn harder)")
        return
    lev = est.lever
    t_base = Rbl @ T_li[:3, 3] + Tbl[:3, 3]
    t_base[:2] = res.lever_xy_m
    cov_base = Rbl @ lev.covariance_m2 @ Rbl.T
    cov_base[:2, :] = cov_base[:, :2] = 0.0  # the plane's now the wheels', uncorrelated with the vertical
    cov_base[:2, :2] = res.lever_cov_m2
    cov = Rbl.T @ cov_base @ Rbl
    sig = np.sqrt(np.clip(np.diag(cov), 0, None))
    better = (sig <= MAX_SIGMA_M) & (sig < lev.sigma_m)
    if not better.any():
        return
    t_new = np.where(better, Rbl.T @ (t_base - Tbl[:3, 3]), lev.t_lidar_imu_m)
    est.lever = replace(lev, t_lidar_imu_m=t_new, covariance_m2=np.where(np.outer(better, better), cov, lev.covariance_m2),
                        sigma_m=np.where(better, sig, lev.sigma_m), observable=lev.observable | better)
    gained = {f"lever_arm_{'xyz'[k]}" for k in np.flatnonzero(better)}
    whole = [s for s in est.skipped if s.key == "lever_arm"]
    est.skipped = [s for s in est.skipped if s.key not in gained and s.key != "lever_arm"]
    for k in np.flatnonzero(~est.lever.observable):  # a whole-lever-arm item now names only the axes left
        key = f"lever_arm_{'xyz'[k]}"
        if whole and all(s.key != key for s in est.skipped):
            est.skip(key, f"the lever arm along the LiDAR {'xyz'[k]} axis", whole[0].reason)
    est.notes.append(f"the lever arm in the base plane from the wheels' accelerations: x {res.lever_xy_m[0]:+.3f} m, "
                     f"y {res.lever_xy_m[1]:+.3f} m, 1-sigma {100 * sig_xy[0]:.1f} / {100 * sig_xy[1]:.1f} cm")

