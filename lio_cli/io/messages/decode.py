"""Decode IMU, odometry, pose, TF and NavSatFix messages into typed records; dispatch by message type."""

from __future__ import annotations

import math

import numpy as np

from ...errors import InputError
from ...geometry import pose_from_xyz_quat_one
from .pointcloud import stamp_to_ns
from ...model.records import NavSatFixRecord, OdometryRecord, PoseRecord, TransformRecord

POINTCLOUD2 = "sensor_msgs/msg/PointCloud2"
LASERSCAN = "sensor_msgs/msg/LaserScan"
IMU = "sensor_msgs/msg/Imu"
ODOMETRY = "nav_msgs/msg/Odometry"
TWIST_STAMPED = "geometry_msgs/msg/TwistStamped"
POSE_STAMPED = "geometry_msgs/msg/PoseStamped"
TRANSFORM_STAMPED = "geometry_msgs/msg/TransformStamped"
TF_MESSAGE = "tf2_msgs/msg/TFMessage"
NAVSATFIX = "sensor_msgs/msg/NavSatFix"

# Which message types can feed which role.
KIND_TYPES: dict[str, tuple[str, ...]] = {
    "lidar": (POINTCLOUD2, LASERSCAN),
    "imu": (IMU,),
    "wheel": (ODOMETRY, TWIST_STAMPED),
    "gt": (POSE_STAMPED, TRANSFORM_STAMPED, ODOMETRY),
    "gps": (NAVSATFIX,),
}
KIND_FLAGS = {"lidar": "--lidar-topic", "imu": "--imu-topic", "wheel": "--wheel-topic", "gt": "--gt-topic",
              "gps": "--gps-topic"}


def _vec(v) -> np.ndarray:
    return np.array([v.x, v.y, v.z], dtype=np.float64)


def _pose_of(position, orientation, what: str) -> np.ndarray:
    xyz = (float(position.x), float(position.y), float(position.z))
    q = (float(orientation.x), float(orientation.y), float(orientation.z), float(orientation.w))
    qa = np.array(q)
    norm = math.sqrt(float(qa.dot(qa)))  # np.linalg.norm's own sum (BLAS dot), so the same bits, at a third the cost
    if not all(map(math.isfinite, xyz + q)) or norm < 1e-6:
        raise InputError(f"{what} holds a non-finite position or a zero/NaN quaternion")
    return pose_from_xyz_quat_one(xyz, [c / norm for c in q])


def imu_sample(msg) -> tuple[int, np.ndarray, np.ndarray]:
    """(stamp_ns, gyro rad/s (3,), accel m/s^2 (3,)) of one sensor_msgs/Imu."""
    return stamp_to_ns(msg.header.stamp), _vec(msg.angular_velocity), _vec(msg.linear_acceleration)


def decode_odometry(msg, msgtype: str) -> OdometryRecord:
    stamp = stamp_to_ns(msg.header.stamp)
    if msgtype == ODOMETRY:
        tw = msg.twist.twist
        linear, angular = _vec(tw.linear), _vec(tw.angular)
        try:
            pose = _pose_of(msg.pose.pose.position, msg.pose.pose.orientation, "Odometry pose")
        except InputError:
            # velocity-only odometry (a (0,0,0,0) quaternion, as AR.Drone's driver writes): the twist, no pose
            if not (np.isfinite(linear).all() and np.isfinite(angular).all()):
                raise InputError("Odometry holds neither a valid pose (non-finite position or zero/NaN "
                                 "quaternion) nor a finite twist") from None
            pose = None
        return OdometryRecord(stamp, msg.header.frame_id, msg.child_frame_id, pose, linear, angular)
    if msgtype == TWIST_STAMPED:
        tw = msg.twist
        return OdometryRecord(stamp, msg.header.frame_id, msg.header.frame_id, None, _vec(tw.linear), _vec(tw.angular))
    raise InputError(f"cannot read wheel odometry from {msgtype} (expected {ODOMETRY} or {TWIST_STAMPED})")


def decode_pose(msg, msgtype: str) -> PoseRecord:
    stamp = stamp_to_ns(msg.header.stamp)
    if msgtype == POSE_STAMPED:
        return PoseRecord(stamp, msg.header.frame_id, "", _pose_of(msg.pose.position, msg.pose.orientation, "PoseStamped"))
    if msgtype == TRANSFORM_STAMPED:
        tf = msg.transform
        return PoseRecord(stamp, msg.header.frame_id, msg.child_frame_id, _pose_of(tf.translation, tf.rotation, "TransformStamped"))
    if msgtype == ODOMETRY:
        p = msg.pose.pose
        return PoseRecord(stamp, msg.header.frame_id, msg.child_frame_id, _pose_of(p.position, p.orientation, "Odometry pose"))
    raise InputError(f"cannot read a pose from {msgtype} (expected PoseStamped, TransformStamped or Odometry)")


def decode_tf(msg) -> list[TransformRecord]:
    out = []
    for ts in msg.transforms:
        tf = ts.transform
        pose = _pose_of(tf.translation, tf.rotation, f"transform {ts.header.frame_id}->{ts.child_frame_id}")
        out.append(TransformRecord(stamp_to_ns(ts.header.stamp), ts.header.frame_id.lstrip("/"), ts.child_frame_id.lstrip("/"), pose))
    return out


def decode_navsatfix(msg) -> NavSatFixRecord:
    """A sensor_msgs/NavSatFix as it is (no validity check: see ``NavSatFixRecord.invalid_reason``)."""
    cov = np.asarray(msg.position_covariance, dtype=np.float64)
    if cov.size != 9:
        raise InputError(f"NavSatFix position_covariance has {cov.size} values, expected 9")
    return NavSatFixRecord(stamp_to_ns(msg.header.stamp), msg.header.frame_id, int(msg.status.status),
                           int(msg.status.service), float(msg.latitude), float(msg.longitude), float(msg.altitude),
                           cov.reshape(3, 3), int(msg.position_covariance_type))
