"""Decoded topics (``io.series`` columns, a GPS track, a trajectory) -> the fusion core's input series.

What a message carries is decided here, message by message, as ROS documents it: an IMU orientation is valid
when ``orientation_covariance[0] != -1`` and the quaternion has unit length; a covariance of 0 is "unknown"
(the core then uses its default noise), a variance of 1e3 or more marks a component as not measured
(robot_localization's convention, e.g. 1e6 on a wheel odometry's roll rate); a yaw rate that is exactly 0 in
every message was never filled. Nothing is dropped here: the core sorts, de-duplicates and counts.
"""

from __future__ import annotations

import numpy as np

from ...core.fuse import GpsSeries, ImuSeries, PoseSeries, WheelSeries
from ...geometry import pose_from_xyz_quat, quat_xyzw_to_rot
from ...io.messages.decode import ODOMETRY
from ...io.sensors.series import ImuColumns, MotionColumns
from ...model.calibration import WheelCalibration
from ...model.gps import GpsTrack
from ...model.records import MAX_TWIST_MPS, on_lidar_clock

UNMEASURED_VAR = 1e3  # a variance this large says "not measured"
UNIT_QUAT_TOL = 1e-2  # |q| - 1 of a quaternion that counts as a rotation
FRAME_TEST_MIN_SPEED_MPS = 0.2  # samples slower than this cannot tell a twist's frame
FRAME_TEST_MIN_SAMPLES = 20
LATERAL_SPEED_MPS = 0.1  # a wheel twist whose lateral speed exceeds this often is from a holonomic base or a drone
LATERAL_SHARE = 0.05


def unit_quaternions(q: np.ndarray) -> np.ndarray:
    """(N,) True where a quaternion is finite and of unit length (a (0,0,0,0) placeholder is not)."""
    with np.errstate(invalid="ignore"):
        n = np.linalg.norm(q, axis=1)
        return np.isfinite(n) & (np.abs(n - 1.0) <= UNIT_QUAT_TOL)


def imu_series(cols: ImuColumns, T_base_imu: np.ndarray, offset_ns: int = 0, gyro_bias=None,
               accel_bias=None) -> ImuSeries:
    """IMU samples on the common clock (``offset_ns`` added), calibration biases removed; the orientation
    is valid where the message says so (covariance[0] != -1) and the quaternion is a rotation."""
    gyro = cols.gyro_radps - (np.asarray(gyro_bias) if gyro_bias is not None else 0.0)
    accel = cols.accel_mps2 - (np.asarray(accel_bias) if accel_bias is not None else 0.0)
    valid = (cols.orientation_cov[:, 0] != -1.0) & unit_quaternions(cols.quat_xyzw)
    return ImuSeries(on_lidar_clock(cols.stamps_ns, offset_ns), gyro, accel, T_base_imu, cols.quat_xyzw, valid,
                     cols.orientation_cov.reshape(-1, 3, 3))


def _component_var(cov: np.ndarray | None, n: int, idx: list[int]) -> tuple[np.ndarray | None, np.ndarray]:
    """(variances (n,len(idx)) or None, (n,len(idx)) True where the component is marked unmeasured)."""
    if cov is None:
        return None, np.zeros((n, len(idx)), bool)
    var = cov[:, idx]
    with np.errstate(invalid="ignore"):
        return var, var >= UNMEASURED_VAR


def twist_frame(cols: MotionColumns) -> tuple[str, str]:
    """Which frame an Odometry twist is in, from its own poses: ``child`` (REP 105: the base, so
    ``R_world_base v`` matches the poses' velocity) or ``parent`` (some drivers: ``v`` itself matches)."""
    if cols.msgtype != ODOMETRY:
        return "child", "TwistStamped: the twist of its header frame, taken as the base"
    order = np.argsort(cols.stamps_ns, kind="stable")
    st, p, q, v = cols.stamps_ns[order], cols.position_m[order], cols.quat_xyzw[order], cols.linear_mps[order]
    if len(st) < 3:
        return "child", "REP 105 (too few messages to check against the poses)"
    dt = (st[2:] - st[:-2]) * 1e-9
    with np.errstate(invalid="ignore", divide="ignore"):
        v_fd = (p[2:] - p[:-2]) / dt[:, None]
    mid = slice(1, -1)
    ok = unit_quaternions(q[mid]) & np.all(np.isfinite(v_fd), axis=1) & np.all(np.abs(v[mid]) <= MAX_TWIST_MPS, axis=1) \
        & (np.abs(v_fd) <= MAX_TWIST_MPS).all(axis=1) & (dt > 0) & (np.linalg.norm(np.nan_to_num(v_fd), axis=1) > FRAME_TEST_MIN_SPEED_MPS)
    if np.count_nonzero(ok) < FRAME_TEST_MIN_SAMPLES:
        return "child", "REP 105 (the poses cannot tell: no valid orientation or too little motion)"
    qn = q[mid][ok] / np.linalg.norm(q[mid][ok], axis=1)[:, None]
    R = quat_xyzw_to_rot(qn)
    e_child = float(np.median(np.linalg.norm(np.einsum("nij,nj->ni", R, v[mid][ok]) - v_fd[ok], axis=1)))
    e_parent = float(np.median(np.linalg.norm(v[mid][ok] - v_fd[ok], axis=1)))
    if e_parent < 0.5 * e_child:
        return "parent", (f"the twist matches the poses' velocity in {cols.frame_id or 'the parent frame'} "
                          f"(median misfit {e_parent:.3f} m/s) and not in {cols.child_frame_id or 'the child frame'} "
                          f"({e_child:.3f} m/s): rotated into the base with each message's orientation")
    return "child", f"REP 105, confirmed by the poses (median misfit {e_child:.3f} m/s; {e_parent:.3f} m/s as parent)"


def wheel_series(cols: MotionColumns, frame: str, R_base_child: np.ndarray | None = None) -> WheelSeries:
    """Body velocity and yaw rate of the base from a twist (``frame``: child or parent, see ``twist_frame``).
    A component whose variance marks it unmeasured is NaN; a yaw rate that is 0 in every message is NaN."""
    n = len(cols)
    lin = cols.linear_mps.copy()
    if frame == "parent":  # v_child = R_parent_child^T v_parent, with each message's own orientation
        ok = unit_quaternions(cols.quat_xyzw)
        R = np.broadcast_to(np.eye(3), (n, 3, 3)).copy()
        if np.any(ok):
            R[ok] = quat_xyzw_to_rot(cols.quat_xyzw[ok] / np.linalg.norm(cols.quat_xyzw[ok], axis=1)[:, None])
        lin = np.einsum("nji,nj->ni", R, lin)
        lin[~ok] = np.nan
    if R_base_child is not None:
        lin = lin @ np.asarray(R_base_child).T
    yaw = cols.angular_radps[:, 2].copy()
    vvar, v_unmeasured = _component_var(cols.twist_cov, n, [0, 7, 14])
    yvar, y_unmeasured = _component_var(cols.twist_cov, n, [35])
    lin[v_unmeasured] = np.nan
    yaw[y_unmeasured[:, 0]] = np.nan
    if n and not np.any(np.nan_to_num(yaw)):
        yaw[:] = np.nan
    return WheelSeries(cols.stamps_ns.copy(), lin, yaw, vvar, None if yvar is None else yvar[:, 0])


def calibrated_wheel(wheel: WheelSeries, scales: WheelCalibration) -> WheelSeries:
    """The twist corrected by ``lio calibrate``'s scale factors (true speed = speed_scale x wheel speed, true yaw
    rate = yaw_rate_scale x wheel yaw rate); variances scaled alike."""
    sv, sw = scales.speed_scale, scales.yaw_rate_scale
    return WheelSeries(wheel.stamps_ns, wheel.velocity_mps * sv, wheel.yaw_rate_radps * sw,
                       None if wheel.velocity_var is None else wheel.velocity_var * sv**2,
                       None if wheel.yaw_rate_var is None else wheel.yaw_rate_var * sw**2,
                       scales.speed_scale_sigma / sv)


def carries_lateral_speed(wheel: WheelSeries) -> bool:
    """The twist has a real lateral component (holonomic base, drone): a forward speed with a
    non-holonomic constraint would contradict it."""
    vy = wheel.velocity_mps[:, 1]
    with np.errstate(invalid="ignore"):
        fast = np.abs(vy) > np.maximum(LATERAL_SPEED_MPS, 0.2 * np.abs(wheel.velocity_mps[:, 0]))
    return len(vy) > 0 and np.count_nonzero(fast) > LATERAL_SHARE * len(vy)


def pose_series(cols: MotionColumns) -> PoseSeries:
    """Poses of a pose/odometry topic; an invalid rotation (e.g. quaternion 0,0,0,0) stays invalid for the
    core to count; Odometry pose variances give isotropic sigmas (unknown or unmeasured: the default)."""
    n = len(cols)
    ok = unit_quaternions(cols.quat_xyzw) & np.all(np.isfinite(cols.position_m), axis=1)
    T = np.zeros((n, 4, 4))
    T[:, :3, 3], T[:, 3, 3] = cols.position_m, 1.0
    if np.any(ok):
        q = cols.quat_xyzw[ok] / np.linalg.norm(cols.quat_xyzw[ok], axis=1)[:, None]
        T[ok] = pose_from_xyz_quat(cols.position_m[ok], q)
    ps = rs = None
    if cols.pose_cov is not None:
        ps, rs = _iso_sigma(cols.pose_cov[:, [0, 7, 14]]), _iso_sigma(cols.pose_cov[:, [21, 28, 35]])
    return PoseSeries(cols.stamps_ns.copy(), T, ps, rs)


def _iso_sigma(var: np.ndarray) -> np.ndarray:
    """sqrt of the mean of the measured, known variances per row; NaN (the core's default) where none."""
    with np.errstate(invalid="ignore"):
        good = np.isfinite(var) & (var > 0) & (var < UNMEASURED_VAR)
        cnt = good.sum(axis=1)
        mean = np.where(good, var, 0.0).sum(axis=1) / np.maximum(cnt, 1)
    return np.where(cnt > 0, np.sqrt(mean), np.nan)


def trajectory_series(stamps_ns: np.ndarray, poses: np.ndarray) -> PoseSeries:
    return PoseSeries(np.asarray(stamps_ns, np.int64), np.asarray(poses, np.float64))


def gps_series(track: GpsTrack, antenna_m: np.ndarray | None = None) -> GpsSeries:
    """Valid fixes in ENU; a covariance of type 0 (unknown) is NaN, so the core uses its default; ``antenna_m``:
    the antenna's position on the base (base axes)."""
    cov = track.covariance_m2.copy()
    cov[track.covariance_type == 0] = np.nan
    return GpsSeries(track.stamps_ns.copy(), track.enu_m.copy(), cov, antenna_m=antenna_m)


__all__ = ["carries_lateral_speed", "gps_series", "imu_series", "pose_series", "trajectory_series", "twist_frame",
           "unit_quaternions", "wheel_series"]
