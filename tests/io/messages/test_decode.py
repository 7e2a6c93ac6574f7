"""Odometry, TwistStamped, PoseStamped, TransformStamped and TF decoding into typed records."""

from __future__ import annotations

import numpy as np
import pytest
from rosbags.typesys import Stores, get_typestore

from lio_cli.errors import InputError
from lio_cli.geometry import make_pose, so3_exp
from lio_cli.io.messages.decode import (
    ODOMETRY,
    POSE_STAMPED,
    TRANSFORM_STAMPED,
    TWIST_STAMPED,
    decode_odometry,
    decode_pose,
    decode_tf,
    imu_sample,
)
from lio_cli.io.messages.encode import MessageFactory

POSE_TOL = 1e-12
STAMP_NS = 1_700_000_000_123_456_789
T = make_pose(so3_exp(np.array([0.3, -0.2, 1.1])), np.array([1.0, -2.0, 0.5]))


@pytest.fixture(scope="module", params=[Stores.ROS1_NOETIC, Stores.ROS2_HUMBLE], ids=["ros1", "ros2"])
def make(request) -> MessageFactory:
    ts = get_typestore(request.param)
    if "tf2_msgs/msg/TFMessage" not in ts.types:
        from rosbags.typesys import get_types_from_msg

        ts.register(get_types_from_msg("geometry_msgs/TransformStamped[] transforms\n", "tf2_msgs/msg/TFMessage"))
    return MessageFactory(ts)


def test_imu_sample(make):
    stamp, gyro, accel = imu_sample(make.imu(STAMP_NS, "imu", [0.1, 0.2, 0.3], [1.0, 2.0, 9.8]))
    assert stamp == STAMP_NS
    np.testing.assert_array_equal(gyro, [0.1, 0.2, 0.3])
    np.testing.assert_array_equal(accel, [1.0, 2.0, 9.8])


def test_odometry_gives_pose_and_twist(make):
    rec = decode_odometry(make.odometry(STAMP_NS, "odom", "base_link", T, [1.5, 0, 0], [0, 0, 0.25]), ODOMETRY)
    assert (rec.stamp_ns, rec.frame_id, rec.child_frame_id) == (STAMP_NS, "odom", "base_link")
    np.testing.assert_allclose(rec.pose, T, atol=POSE_TOL)
    np.testing.assert_array_equal(rec.linear_mps, [1.5, 0, 0])
    np.testing.assert_array_equal(rec.angular_radps, [0, 0, 0.25])


def test_twist_stamped_has_no_pose(make):
    rec = decode_odometry(make.twist_stamped(STAMP_NS, "base_link", [0.5, 0, 0], [0, 0, -0.1]), TWIST_STAMPED)
    assert rec.pose is None and rec.stamp_ns == STAMP_NS and rec.child_frame_id == "base_link"
    np.testing.assert_array_equal(rec.angular_radps, [0, 0, -0.1])


def test_ground_truth_from_pose_transform_and_odometry(make):
    for msg, typ, child in ((make.pose_stamped(STAMP_NS, "world", T), POSE_STAMPED, ""),
                            (make.transform_stamped(STAMP_NS, "world", "base", T), TRANSFORM_STAMPED, "base"),
                            (make.odometry(STAMP_NS, "world", "base", T, [0, 0, 0], [0, 0, 0]), ODOMETRY, "base")):
        rec = decode_pose(msg, typ)
        assert (rec.stamp_ns, rec.frame_id, rec.child_frame_id) == (STAMP_NS, "world", child)
        np.testing.assert_allclose(rec.pose, T, atol=POSE_TOL)


def test_unnormalised_quaternion_is_normalised_and_zero_one_rejected(make):
    msg = make.pose_stamped(STAMP_NS, "world", T)
    q = msg.pose.orientation
    q.x, q.y, q.z, q.w = 2 * q.x, 2 * q.y, 2 * q.z, 2 * q.w
    np.testing.assert_allclose(decode_pose(msg, POSE_STAMPED).pose, T, atol=1e-9)
    q.x = q.y = q.z = q.w = 0.0
    with pytest.raises(InputError, match="PoseStamped holds a non-finite position or a zero/NaN quaternion"):
        decode_pose(msg, POSE_STAMPED)


def test_twist_only_odometry_keeps_its_twist_without_a_pose(make):
    """A zero quaternion with a finite twist (AR.Drone's velocity-only odometry) is a twist record; with a NaN
    twist as well it is bad input."""
    msg = make.odometry(STAMP_NS, "odom", "base_link", T, [1.5, 0, 0], [0, 0, 0.25])
    q = msg.pose.pose.orientation
    q.x = q.y = q.z = q.w = 0.0
    rec = decode_odometry(msg, ODOMETRY)
    assert rec.pose is None
    np.testing.assert_array_equal(rec.linear_mps, [1.5, 0, 0])
    np.testing.assert_array_equal(rec.angular_radps, [0, 0, 0.25])
    msg.twist.twist.linear.x = float("nan")
    with pytest.raises(InputError, match="neither a valid pose .* nor a finite twist"):
        decode_odometry(msg, ODOMETRY)


def test_wrong_types_are_input_errors(make):
    with pytest.raises(InputError, match="cannot read wheel odometry from geometry_msgs/msg/PoseStamped"):
        decode_odometry(make.pose_stamped(STAMP_NS, "w", T), POSE_STAMPED)
    with pytest.raises(InputError, match="cannot read a pose from geometry_msgs/msg/TwistStamped"):
        decode_pose(make.twist_stamped(STAMP_NS, "w", [0, 0, 0], [0, 0, 0]), TWIST_STAMPED)


def test_tf_message_strips_leading_slashes(make):
    msg = make.tf_message([make.transform_stamped(STAMP_NS, "/base_link", "/imu", T),
                           make.transform_stamped(STAMP_NS, "imu", "lidar", np.eye(4))])
    recs = decode_tf(msg)
    assert [(r.parent, r.child) for r in recs] == [("base_link", "imu"), ("imu", "lidar")]
    np.testing.assert_allclose(recs[0].pose, T, atol=POSE_TOL)


def test_message_poses_have_the_bits_of_numpys_normalisation():
    """A message's pose is normalised by its quaternion's norm in Python floats: the same bits as the numpy
    version it replaced (np.linalg.norm, then q / norm) on 20 000 random poses of all sizes, and the same refusals."""
    from types import SimpleNamespace as NS

    from lio_cli.geometry import pose_from_xyz_quat_one

    def pose_of(p, q):
        return decode_pose(NS(header=NS(stamp=NS(sec=1, nanosec=0), frame_id="w"), pose=NS(
            position=NS(x=p[0], y=p[1], z=p[2]), orientation=NS(x=q[0], y=q[1], z=q[2], w=q[3]))), POSE_STAMPED).pose

    def numpy_pose(p, q):
        q = np.array(q, dtype=np.float64)
        norm = float(np.linalg.norm(q))
        return pose_from_xyz_quat_one(p, (q / norm).tolist())

    rng = np.random.default_rng(3)
    qs = rng.normal(size=(20_000, 4)) * 10.0 ** rng.uniform(-5, 5, size=(20_000, 1))
    ps = rng.normal(size=(20_000, 3)) * 100.0
    for p, q in zip(ps.tolist(), qs.tolist()):
        assert pose_of(p, q).tobytes() == numpy_pose(p, q).tobytes()
    for p, q in (([0.0, np.nan, 0.0], [0, 0, 0, 1]), ([0.0] * 3, [0, 0, np.inf, 1]), ([0.0] * 3, [0, 0, 0, 1e-7])):
        with pytest.raises(InputError, match="^PoseStamped holds a non-finite position or a zero/NaN quaternion$"):
            pose_of(p, q)
