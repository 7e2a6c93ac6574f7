"""FrameTree chains and /tf_static reading."""

from __future__ import annotations

import numpy as np
import pytest

from lio_cli.errors import InputError
from lio_cli.geometry import inv_pose, make_pose, so3_exp
from lio_cli.io.logs.reader import open_log
from lio_cli.model.records import TransformRecord
from lio_cli.io.sensors.tf import FrameTree, TfConflict, read_static_frames

POSE_TOL = 1e-12


def pose(seed: int) -> np.ndarray:
    rng = np.random.default_rng(seed)
    return make_pose(so3_exp(rng.normal(size=3)), rng.normal(size=3))


def test_chains_resolve_in_both_directions():
    A, B, C = pose(1), pose(2), pose(3)
    tree = FrameTree([TransformRecord(0, "base", "imu", A), TransformRecord(0, "imu", "lidar", B),
                      TransformRecord(0, "base", "wheel", C)])
    np.testing.assert_allclose(tree.lookup("base", "lidar"), A @ B, atol=POSE_TOL)
    np.testing.assert_allclose(tree.lookup("lidar", "base"), inv_pose(A @ B), atol=POSE_TOL)
    np.testing.assert_allclose(tree.lookup("wheel", "lidar"), inv_pose(C) @ A @ B, atol=POSE_TOL)
    np.testing.assert_array_equal(tree.lookup("/imu", "imu"), np.eye(4))
    assert tree.frames == ["base", "imu", "lidar", "wheel"]


def test_unconnected_or_unknown_frames_give_none():
    tree = FrameTree([TransformRecord(0, "a", "b", pose(1)), TransformRecord(0, "c", "d", pose(2))])
    assert tree.lookup("a", "d") is None
    assert tree.lookup("a", "nowhere") is None


def test_a_repeated_transform_replaces_the_old_one():
    tree = FrameTree([TransformRecord(0, "a", "b", pose(1)), TransformRecord(5, "a", "b", pose(2))])
    assert len(tree.transforms) == 1
    np.testing.assert_allclose(tree.lookup("a", "b"), pose(2), atol=POSE_TOL)


def test_read_static_frames_from_every_format(logs, write_format):
    path = logs.sensor_log(write_format, duration_s=0.2)
    with open_log(path) as log:
        tree = read_static_frames(log)
    np.testing.assert_allclose(tree.lookup("base_link", "velodyne"), logs.T_BASE_IMU @ logs.T_IMU_LIDAR, atol=1e-9)
    assert tree.frames == ["base_link", "imu_link", "velodyne"]


def test_log_without_tf_static_gives_empty_tree(logs):
    path = logs.write("ros1", lambda w: w.add_topic("/imu", "sensor_msgs/msg/Imu"))
    with open_log(path) as log:
        tree = read_static_frames(log)
    assert tree.frames == [] and tree.lookup("a", "b") is None


def _tf_log(logs, fmt: str, static: bool):
    """/tf at 10 Hz for 1 s: base_link -> imu_link and imu_link -> velodyne fixed, odom -> base_link standing
    still (a moving frame, whatever it shows), base_link -> arm moving; /tf_static with base_link -> imu_link when
    ``static`` (a different value: /tf_static wins)."""
    def build(w):
        m = w.make
        w.add_topic("/tf", "tf2_msgs/msg/TFMessage")
        if static:
            w.add_topic("/tf_static", "tf2_msgs/msg/TFMessage", latching=True)
            w.write("/tf_static", logs.T0_NS, m.tf_message([m.transform_stamped(logs.T0_NS, "base_link", "imu_link", pose(7))]))
        for k in range(10):
            t = logs.T0_NS + k * 100_000_000
            w.write("/tf", t, m.tf_message([
                m.transform_stamped(t, "/base_link", "imu_link", logs.T_BASE_IMU),
                m.transform_stamped(t, "imu_link", "velodyne", logs.T_IMU_LIDAR),
                m.transform_stamped(t, "odom", "base_link", np.eye(4)),
                m.transform_stamped(t, "base_link", "arm", make_pose(t=[0.01 * k, 0, 0]))]))
    return logs.write(fmt, build)


def test_a_mounting_published_on_tf_is_taken_with_a_warning(logs, write_format):
    """Extrinsics on /tf only (a tf1 static_transform_publisher, a recording that missed the latched
    /tf_static): once identity with a warning, which put a 15 s walk 1.2 m off instead of 0.021 m."""
    with open_log(_tf_log(logs, write_format, static=False)) as log:
        tree = read_static_frames(log)
    np.testing.assert_allclose(tree.lookup("base_link", "velodyne"), logs.T_BASE_IMU @ logs.T_IMU_LIDAR, atol=1e-9)
    assert tree.source("base_link", "velodyne") == "/tf"
    assert tree.lookup("base_link", "arm") is None and tree.lookup("odom", "base_link") is None
    assert tree.warnings == [
        "/tf: base_link -> imu_link taken as a mounting (the same over its 10 messages among the first 2000 of /tf; "
        "/tf_static has no chain between them)",
        "/tf: imu_link -> velodyne taken as a mounting (the same over its 10 messages among the first 2000 of /tf; "
        "/tf_static has no chain between them)"]


def test_tf_static_wins_over_tf(logs):
    with open_log(_tf_log(logs, "ros1", static=True)) as log:
        tree = read_static_frames(log)
    np.testing.assert_allclose(tree.lookup("base_link", "imu_link"), pose(7), atol=POSE_TOL)
    assert tree.source("base_link", "imu_link") == "/tf_static" and tree.source("base_link", "velodyne") == "/tf"
    assert len(tree.warnings) == 1 and tree.warnings[0].startswith("/tf: imu_link -> velodyne taken as a mounting")


def test_bad_transform_on_tf_static_names_file_and_topic(logs):
    def build(w):
        w.add_topic("/tf_static", "tf2_msgs/msg/TFMessage")
        tf = w.make.transform_stamped(logs.T0_NS, "base", "imu", np.eye(4))
        tf.transform.rotation.w = 0.0  # a zero quaternion
        w.write("/tf_static", logs.T0_NS, w.make.tf_message([tf]))
    path = logs.write("ros2", build)
    with open_log(path) as log:
        with pytest.raises(InputError) as err:
            read_static_frames(log)
    assert str(err.value) == (f"{path}: /tf_static: transform base->imu holds a non-finite position or a "
                              "zero/NaN quaternion")


@pytest.mark.parametrize("extra, frames", [
    (("lidar", "base"), ("lidar -> base", "base -> lidar")),  # the reverse of an edge, 0.5 m off
    (("imu", "lidar"), ("imu -> lidar", "base -> imu, base -> lidar")),  # a second path, 0.5 m off
])
def test_a_disagreeing_cycle_is_reported_and_stops_lookups_through_it(extra, frames):
    """Chains that disagree: the closing edge is not used; a lookup through any edge of the cycle raises
    naming the frames and the distance; a lookup elsewhere still works."""
    A, B, C = pose(1), pose(2), pose(3)
    T = inv_pose(B) if extra == ("lidar", "base") else inv_pose(A) @ B
    T = T.copy()
    T[0, 3] += 0.5
    tree = FrameTree([TransformRecord(0, "base", "imu", A), TransformRecord(0, "base", "lidar", B),
                      TransformRecord(0, "base", "wheel", C), TransformRecord(0, *extra, T)], where="x.bag: /tf_static")
    assert len(tree.conflicts) == 1 and tree.conflicts[0]["distance_m"] == pytest.approx(0.5, abs=1e-9)
    message = f"x.bag: /tf_static contradicts itself: {frames[0]} disagrees with {frames[1]} by 0.500 m and 0.00 deg"
    assert tree.conflicts[0]["message"] == message
    with pytest.raises(TfConflict, match="contradicts itself"):
        tree.lookup("base", "lidar")
    np.testing.assert_allclose(tree.lookup("base", "wheel"), C, atol=POSE_TOL)


def test_a_cycle_whose_chains_agree_is_accepted():
    A, B = pose(1), pose(2)
    tree = FrameTree([TransformRecord(0, "base", "imu", A), TransformRecord(0, "base", "lidar", B),
                      TransformRecord(0, "imu", "lidar", inv_pose(A) @ B)])
    assert tree.conflicts == []
    np.testing.assert_allclose(tree.lookup("base", "lidar"), B, atol=1e-9)
