"""Clean each source before fusion: sort by stamp, drop duplicated stamps and unusable rows, fill missing
covariances with the defaults. Every decision is counted in the source's ``SourceReport``.

Offline, a late or out-of-order message is simply put back in its place: the estimators then see every
source in stamp order. Cost is O(N log N) in the number of samples, whatever the stamps claim.
"""

from __future__ import annotations

import numpy as np

from ...geometry import quat_xyzw_to_rot
from ...model.records import MAX_IMU_ACCEL_MPS2, MAX_IMU_GYRO_RADPS, MAX_TWIST_MPS, MAX_TWIST_RADPS
from .inputs import GpsSeries, ImuSeries, NoiseOptions, PoseSeries, WheelSeries
from .report import SourceReport

_ROT_TOL = 1e-3  # |R^T R - I| and |det R - 1| a pose rotation may show and still count as a rotation


def order_and_dedupe(stamps_ns: np.ndarray, usable: np.ndarray, report: SourceReport) -> np.ndarray:
    """Indices of the usable samples in stamp order, first of each duplicated stamp kept; counts
    ``reordered`` (stamp below an earlier one in arrival order) and ``duplicate_stamp``."""
    stamps = np.asarray(stamps_ns, dtype=np.int64)
    idx = np.flatnonzero(usable)
    s = stamps[idx]
    if len(s) > 1:
        report.note("reordered", int(np.count_nonzero(s[1:] < np.maximum.accumulate(s)[:-1])))
    order = idx[np.argsort(s, kind="stable")]
    s = stamps[order]
    dup = np.zeros(len(order), dtype=bool)
    dup[1:] = s[1:] == s[:-1]
    report.reject("duplicate_stamp", int(dup.sum()))
    return order[~dup]


def _variance(values: np.ndarray | None, n: int, k: int, default_var: float | np.ndarray, use_msg: bool,
              report: SourceReport, relevant: np.ndarray) -> np.ndarray:
    """(n,k) variances: the message's where finite and positive, else ``default_var`` (a number, or (n,k)
    per message; counted where the component is relevant, i.e. actually measured)."""
    out = np.array(np.broadcast_to(default_var, (n, k)), dtype=np.float64)
    if values is None or not use_msg:
        return out
    v = np.asarray(values, dtype=np.float64).reshape(n, k)
    with np.errstate(invalid="ignore"):
        good = np.isfinite(v) & (v > 0.0)
    out[good] = v[good]
    report.note("default_noise", int(np.count_nonzero(np.any(~good & relevant, axis=1))))
    return out


def clean_imu(imu: ImuSeries, noise: NoiseOptions, report: SourceReport) -> ImuSeries:
    n = len(imu.stamps_ns)
    report.received += n
    gyro = np.asarray(imu.gyro_radps, dtype=np.float64).reshape(n, 3)
    acc = np.asarray(imu.accel_mps2, dtype=np.float64).reshape(n, 3)
    finite = np.all(np.isfinite(gyro), axis=1) & np.all(np.isfinite(acc), axis=1)
    with np.errstate(invalid="ignore"):
        sane = finite & np.all(np.abs(gyro) <= MAX_IMU_GYRO_RADPS, axis=1) & \
            np.all(np.abs(acc) <= MAX_IMU_ACCEL_MPS2, axis=1)
    zero = sane & ~np.any(gyro, axis=1) & ~np.any(acc, axis=1)
    report.reject("nan", int(np.count_nonzero(~finite)))
    report.reject("out_of_range", int(np.count_nonzero(finite & ~sane)))
    report.reject("all_zero", int(np.count_nonzero(zero)))
    keep = order_and_dedupe(imu.stamps_ns, sane & ~zero, report)
    q = valid = cov = None
    if imu.orientation_xyzw is not None:
        q = np.asarray(imu.orientation_xyzw, dtype=np.float64).reshape(n, 4)[keep]
        valid = np.ones(len(keep), bool)
        if imu.orientation_valid is not None:
            valid &= np.asarray(imu.orientation_valid, bool)[keep]
        norm = np.linalg.norm(np.where(np.isfinite(q), q, 0.0), axis=1)
        valid &= np.all(np.isfinite(q), axis=1) & (norm > 0.5)
        raw = None
        if imu.orientation_cov is not None:
            raw = np.asarray(imu.orientation_cov, np.float64).reshape(n, 3, 3)[keep]
        if raw is not None:
            valid &= ~(raw[:, 0, 0] == -1.0)  # ROS: orientation_covariance[0] = -1 means "no orientation"
        report.note("orientation_absent", int(np.count_nonzero(~valid)))
        q = np.where(valid[:, None], q / np.where(norm > 0.5, norm, 1.0)[:, None], np.array([0, 0, 0, 1.0]))
        cov = np.broadcast_to(np.eye(3) * noise.orientation_sigma_rad**2, (len(keep), 3, 3)).copy()
        if raw is not None and noise.use_message_covariance:
            diag = np.einsum("nii->ni", raw)
            with np.errstate(invalid="ignore"):
                good = np.all(np.isfinite(raw), axis=(1, 2)) & np.all(diag > 0.0, axis=1)
            cov[good] = raw[good]
            report.note("default_noise", int(np.count_nonzero(~good & valid)))
        elif raw is None:
            report.note("default_noise", int(np.count_nonzero(valid)))
    return ImuSeries(np.asarray(imu.stamps_ns, np.int64)[keep], gyro[keep], acc[keep],
                     np.asarray(imu.T_base_imu, np.float64), q, valid, cov)


def clean_wheel(wheel: WheelSeries, use: set[str], noise: NoiseOptions, report: SourceReport) -> WheelSeries:
    n = len(wheel.stamps_ns)
    report.received += n
    vel = np.asarray(wheel.velocity_mps, dtype=np.float64).reshape(n, 3).copy()
    yaw = np.asarray(wheel.yaw_rate_radps, dtype=np.float64).reshape(n).copy()
    with np.errstate(invalid="ignore"):
        wild = np.isfinite(vel) & (np.abs(vel) > MAX_TWIST_MPS), np.isfinite(yaw) & (np.abs(yaw) > MAX_TWIST_RADPS)
    any_wild = np.any(wild[0], axis=1) | wild[1]
    vel[~np.isfinite(vel) | wild[0]] = np.nan
    yaw[~np.isfinite(yaw) | wild[1]] = np.nan
    has = np.zeros(n, bool)
    if "speed" in use:
        has |= np.isfinite(vel[:, 0])
    if "velocity" in use:
        has |= np.any(np.isfinite(vel), axis=1)
    if "yaw_rate" in use:
        has |= np.isfinite(yaw)
    report.reject("out_of_range", int(np.count_nonzero(~has & any_wild)))  # a row left without a usable value
    report.reject("nan", int(np.count_nonzero(~has & ~any_wild)))
    keep = order_and_dedupe(wheel.stamps_ns, has, report)
    vel, yaw = vel[keep], yaw[keep]
    m = len(keep)
    vvar = None if wheel.velocity_var is None else np.asarray(wheel.velocity_var, np.float64).reshape(n, 3)[keep]
    yvar = None if wheel.yaw_rate_var is None else np.asarray(wheel.yaw_rate_var, np.float64).reshape(n, 1)[keep]
    relevant_v = np.isfinite(vel) if ("velocity" in use or "speed" in use) else np.zeros((m, 3), bool)
    speed = np.sqrt(np.nansum(vel * vel, axis=1))[:, None]  # a scale or an angle error: every component
    default_vvar = noise.wheel_speed_sigma_mps**2 + (noise.wheel_speed_rel_sigma * speed)**2  # (m,1): every component
    velocity_var = _variance(vvar, m, 3, default_vvar, noise.use_message_covariance, report, relevant_v)
    yaw_var = _variance(yvar, m, 1, noise.wheel_yaw_rate_sigma_radps**2, noise.use_message_covariance,
                        report, (np.isfinite(yaw) & ("yaw_rate" in use))[:, None])[:, 0]
    return WheelSeries(np.asarray(wheel.stamps_ns, np.int64)[keep], vel, yaw, velocity_var, yaw_var,
                       wheel.speed_scale_sigma)


def clean_odom(odom: PoseSeries, noise: NoiseOptions, report: SourceReport) -> PoseSeries:
    n = len(odom.stamps_ns)
    report.received += n
    T = np.asarray(odom.poses, dtype=np.float64).reshape(n, 4, 4)
    finite = np.all(np.isfinite(T.reshape(n, 16)), axis=1)
    R = np.where(finite[:, None, None], T[:, :3, :3], np.eye(3))
    ortho = np.abs(np.einsum("nji,njk->nik", R, R) - np.eye(3)).reshape(n, 9).max(axis=1) < _ROT_TOL
    det_ok = np.abs(np.linalg.det(R) - 1.0) < _ROT_TOL
    ok = finite & ortho & det_ok
    report.reject("nan", int(np.count_nonzero(~finite)))
    report.reject("invalid_pose", int(np.count_nonzero(finite & ~ok)))
    keep = order_and_dedupe(odom.stamps_ns, ok, report)
    m = len(keep)
    use_msg = noise.use_message_covariance

    def sigma(values, default: float) -> np.ndarray:
        var = None if values is None else np.asarray(values, np.float64)[keep] ** 2
        return np.sqrt(_variance(var, m, 1, default**2, use_msg, report, np.ones((m, 1), bool))[:, 0])

    ps, rs = sigma(odom.position_sigma_m, noise.odom_position_sigma_m), sigma(odom.rotation_sigma_rad,
                                                                               noise.odom_rotation_sigma_rad)
    return PoseSeries(np.asarray(odom.stamps_ns, np.int64)[keep], T[keep], ps, rs)


def clean_gps(gps: GpsSeries, noise: NoiseOptions, report: SourceReport) -> GpsSeries:
    n = len(gps.stamps_ns)
    report.received += n
    pos = np.asarray(gps.position_enu_m, dtype=np.float64).reshape(n, 3)
    valid = np.ones(n, bool) if gps.valid is None else np.asarray(gps.valid, bool).reshape(n)
    finite = np.all(np.isfinite(pos), axis=1)
    report.reject("no_fix", int(np.count_nonzero(~valid)))
    report.reject("nan", int(np.count_nonzero(valid & ~finite)))
    keep = order_and_dedupe(gps.stamps_ns, valid & finite, report)
    m = len(keep)
    cov = np.broadcast_to(np.diag([noise.gps_position_sigma_m**2] * 2 + [noise.gps_vertical_sigma_m**2]),
                          (m, 3, 3)).copy()
    if gps.cov_m2 is not None and noise.use_message_covariance:
        raw = np.asarray(gps.cov_m2, np.float64).reshape(n, 3, 3)[keep]
        with np.errstate(invalid="ignore"):
            good = np.all(np.isfinite(raw), axis=(1, 2)) & np.all(np.einsum("nii->ni", raw) > 0.0, axis=1)
        cov[good] = raw[good]
        report.note("default_noise", int(np.count_nonzero(~good)))
    return GpsSeries(np.asarray(gps.stamps_ns, np.int64)[keep], pos[keep], cov, np.ones(m, bool),
                     antenna_m=gps.antenna_m)


def orientation_to_base(imu: ImuSeries) -> np.ndarray:
    """R_world_base (N,3,3) from the IMU's own orientation estimate (identity where invalid)."""
    R_wi = quat_xyzw_to_rot(imu.orientation_xyzw)
    return R_wi @ imu.T_base_imu[:3, :3].T


def median_period_ns(stamps_ns: np.ndarray) -> int:
    if len(stamps_ns) < 2:
        return 0
    return int(np.median(np.diff(stamps_ns)))


def gap_threshold_ns(stamps_ns: np.ndarray, gap_periods: float, min_gap_ns: int) -> int:
    """A pause longer than this is a gap: ``gap_periods`` median periods, at least ``min_gap_ns``."""
    return max(int(gap_periods * median_period_ns(stamps_ns)), int(min_gap_ns))


def count_gaps(stamps_ns: np.ndarray, threshold_ns: int, report: SourceReport) -> None:
    if len(stamps_ns) > 1:
        report.note("gaps", int(np.count_nonzero(np.diff(stamps_ns) > threshold_ns)))
