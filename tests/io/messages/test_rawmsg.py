"""The raw PointCloud2/Imu/Odometry/TFMessage parsers agree with rosbags' typestore on ROS 1 and CDR bytes,
alignment included."""

from __future__ import annotations

import struct

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from rosbags.typesys import Stores, get_types_from_msg, get_typestore

from lio_cli.io.logs.writer import TF_MESSAGE_DEF
from lio_cli.io.messages.encode import MessageFactory
from lio_cli.io.messages.decode import decode_odometry, decode_pose, decode_tf
from lio_cli.io.messages.rawmsg import parse_imu, parse_odometry, parse_pointcloud2, parse_tf

STORES = {"ros1": get_typestore(Stores.ROS1_NOETIC), "cdr": get_typestore(Stores.ROS2_HUMBLE)}
STORES["ros1"].register(get_types_from_msg(TF_MESSAGE_DEF, "tf2_msgs/msg/TFMessage"))  # not in the ROS 1 store
MAKE = {k: MessageFactory(v) for k, v in STORES.items()}
SETTINGS = settings(max_examples=40, deadline=None, derandomize=True)
names = st.text(alphabet="abcdefghijklmnopqrstuvwxyz_", min_size=0, max_size=11)


def serialise(kind: str, msg, typ: str, little_endian: bool = True) -> bytes:
    ts = STORES[kind]
    if kind == "ros1":
        return bytes(ts.serialize_ros1(msg, typ))
    return bytes(ts.serialize_cdr(msg, typ, little_endian=little_endian))


@SETTINGS
@given(kind=st.sampled_from(["ros1", "cdr"]), frame=names, seed=st.integers(0, 2**16))
def test_imu_matches_typestore(kind, frame, seed):
    rng = np.random.default_rng(seed)
    stamp = int(rng.integers(0, 2**31)) * 10**9 + int(rng.integers(0, 10**9))
    msg = MAKE[kind].imu(stamp, frame, rng.normal(size=3), rng.normal(size=3))
    raw = serialise(kind, msg, "sensor_msgs/msg/Imu")
    parsed = parse_imu(raw, kind == "cdr")
    assert parsed.stamp_ns == stamp and parsed.frame_id == frame
    assert parsed.gyro_radps == (msg.angular_velocity.x, msg.angular_velocity.y, msg.angular_velocity.z)
    assert parsed.accel_mps2 == (msg.linear_acceleration.x, msg.linear_acceleration.y, msg.linear_acceleration.z)


@SETTINGS
@given(kind=st.sampled_from(["ros1", "cdr"]), frame=names, child=names, seed=st.integers(0, 2**16))
def test_odometry_matches_typestore(kind, frame, child, seed):
    """Every attribute lio reads, and the records decode_odometry / decode_pose make of it, as from the typestore
    (frame names of every length: the CDR alignment after each string)."""
    rng = np.random.default_rng(seed)
    stamp = int(rng.integers(0, 2**31)) * 10**9 + int(rng.integers(0, 10**9))
    T = np.eye(4)
    T[:3, 3] = rng.normal(size=3) * 100
    q = rng.normal(size=4)
    x, y, z, w = q / np.linalg.norm(q)
    T[:3, :3] = [[1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
                 [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
                 [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)]]
    msg = MAKE[kind].odometry(stamp, frame, child, T, rng.normal(size=3), rng.normal(size=3))
    raw = serialise(kind, msg, "nav_msgs/msg/Odometry")
    ref = STORES[kind].deserialize_ros1(raw, "nav_msgs/msg/Odometry") if kind == "ros1" else \
        STORES[kind].deserialize_cdr(raw, "nav_msgs/msg/Odometry")
    got = parse_odometry(raw, kind == "cdr")
    assert (got.header.stamp.sec, got.header.stamp.nanosec, got.header.frame_id, got.child_frame_id) == \
        (ref.header.stamp.sec, ref.header.stamp.nanosec, ref.header.frame_id, ref.child_frame_id)
    for a, b in ((got.pose.pose.position, ref.pose.pose.position), (got.twist.twist.linear, ref.twist.twist.linear),
                 (got.twist.twist.angular, ref.twist.twist.angular)):
        assert (a.x, a.y, a.z) == (b.x, b.y, b.z)
    o, r = got.pose.pose.orientation, ref.pose.pose.orientation
    assert (o.x, o.y, o.z, o.w) == (r.x, r.y, r.z, r.w)
    mine, theirs = decode_odometry(got, "nav_msgs/msg/Odometry"), decode_odometry(ref, "nav_msgs/msg/Odometry")
    assert (mine.stamp_ns, mine.frame_id, mine.child_frame_id) == (theirs.stamp_ns, theirs.frame_id, theirs.child_frame_id)
    for field in ("pose", "linear_mps", "angular_radps"):
        np.testing.assert_array_equal(getattr(mine, field), getattr(theirs, field))
    np.testing.assert_array_equal(decode_pose(got, "nav_msgs/msg/Odometry").pose,
                                  decode_pose(ref, "nav_msgs/msg/Odometry").pose)


@SETTINGS
@given(kind=st.sampled_from(["ros1", "cdr"]), frame=names,
       field_names=st.lists(names.filter(bool), min_size=1, max_size=5, unique=True),
       height=st.integers(1, 3), width=st.integers(0, 5))
def test_pointcloud2_matches_typestore(kind, frame, field_names, height, width):
    fields = [(n, ("<f4", "<u2", "<f8", "<u1", "<i4")[i % 5]) for i, n in enumerate(field_names)]
    arr = np.zeros(height * width, dtype=[("x", "<f4"), ("y", "<f4"), ("z", "<f4")] +
                   [(f"f_{n}", d) for n, d in fields])
    arr["x"] = np.arange(len(arr))
    msg = MAKE[kind].pointcloud2(1_700_000_000_123_456_789, frame, arr, height=height)
    raw = serialise(kind, msg, "sensor_msgs/msg/PointCloud2")
    ref = STORES[kind].deserialize_ros1(raw, "sensor_msgs/msg/PointCloud2") if kind == "ros1" else \
        STORES[kind].deserialize_cdr(raw, "sensor_msgs/msg/PointCloud2")
    got = parse_pointcloud2(raw, kind == "cdr")
    assert (got.header.stamp.sec, got.header.stamp.nanosec, got.header.frame_id) == \
        (ref.header.stamp.sec, ref.header.stamp.nanosec, ref.header.frame_id)
    assert (got.height, got.width, got.is_bigendian, got.point_step, got.row_step, got.is_dense) == \
        (ref.height, ref.width, ref.is_bigendian, ref.point_step, ref.row_step, ref.is_dense)
    assert [(f.name, f.offset, f.datatype, f.count) for f in got.fields] == \
        [(f.name, f.offset, f.datatype, f.count) for f in ref.fields]
    np.testing.assert_array_equal(got.data, ref.data)


def test_big_endian_cdr_falls_back_to_the_typestore():
    msg = MAKE["cdr"].imu(5, "imu", [1, 2, 3], [4, 5, 6])
    raw = serialise("cdr", msg, "sensor_msgs/msg/Imu", little_endian=False)
    assert parse_imu(raw, True) is None
    cloud = MAKE["cdr"].pointcloud2(5, "l", np.zeros(2, dtype=[("x", "<f4"), ("y", "<f4"), ("z", "<f4")]))
    assert parse_pointcloud2(serialise("cdr", cloud, "sensor_msgs/msg/PointCloud2", little_endian=False), True) is None
    odom = MAKE["cdr"].odometry(5, "odom", "base", np.eye(4), [1, 2, 3], [4, 5, 6])
    assert parse_odometry(serialise("cdr", odom, "nav_msgs/msg/Odometry", little_endian=False), True) is None


@pytest.mark.parametrize("kind", ["ros1", "cdr"])
def test_truncated_bytes_raise(kind):
    arr = np.zeros(50, dtype=[("x", "<f4"), ("y", "<f4"), ("z", "<f4")])
    raw = serialise(kind, MAKE[kind].pointcloud2(5, "lidar", arr), "sensor_msgs/msg/PointCloud2")
    with pytest.raises((ValueError, struct.error)):
        parse_pointcloud2(raw[: len(raw) // 2], kind == "cdr")
    raw = serialise(kind, MAKE[kind].imu(5, "imu", [1, 2, 3], [4, 5, 6]), "sensor_msgs/msg/Imu")
    with pytest.raises((ValueError, struct.error)):
        parse_imu(raw[:-40], kind == "cdr")
    raw = serialise(kind, MAKE[kind].odometry(5, "odom", "base", np.eye(4), [1, 2, 3], [4, 5, 6]), "nav_msgs/msg/Odometry")
    with pytest.raises((ValueError, struct.error)):
        parse_odometry(raw[:-40], kind == "cdr")
    assert parse_odometry(raw + bytes(8), kind == "cdr") is None  # not the standard layout: the typestore reads it


def _tf_bytes(kind: str, frames: list[tuple[str, str]], seed: int, little_endian: bool = True):
    rng = np.random.default_rng(seed)
    make = MAKE[kind]
    ts = []
    for parent, child in frames:
        T = np.eye(4)
        T[:3, 3] = rng.normal(size=3)
        msg = make.transform_stamped(int(rng.integers(0, 2**31)) * 10**9 + int(rng.integers(0, 10**9)), parent,
                                     child, T)
        msg.transform.rotation = make.quaternion(rng.normal(size=4))  # any quaternion, as a log may hold
        ts.append(msg)
    return serialise(kind, make.tf_message(ts), "tf2_msgs/msg/TFMessage", little_endian)


@SETTINGS
@given(kind=st.sampled_from(["ros1", "cdr"]), frames=st.lists(st.tuples(names, names), max_size=4),
       seed=st.integers(0, 2**16))
def test_tf_message_matches_typestore(kind, frames, seed):
    """Every transform's stamp, frames, translation and rotation, and the records decode_tf makes of them, as
    from the typestore (frame names of every length: the CDR alignment after each string)."""
    raw = _tf_bytes(kind, frames, seed)
    ref = STORES[kind].deserialize_ros1(raw, "tf2_msgs/msg/TFMessage") if kind == "ros1" else \
        STORES[kind].deserialize_cdr(raw, "tf2_msgs/msg/TFMessage")
    got = parse_tf(raw, kind == "cdr")
    assert len(got.transforms) == len(ref.transforms) == len(frames)
    for g, r in zip(got.transforms, ref.transforms):
        assert (g.header.stamp.sec, g.header.stamp.nanosec, g.header.frame_id, g.child_frame_id) == \
            (r.header.stamp.sec, r.header.stamp.nanosec, r.header.frame_id, r.child_frame_id)
        for a, b in ((g.transform.translation, r.transform.translation), (g.transform.rotation, r.transform.rotation)):
            assert all(getattr(a, k) == getattr(b, k) for k in "xyz")
        assert g.transform.rotation.w == r.transform.rotation.w
    try:
        want = [(t.stamp_ns, t.parent, t.child, t.pose.tobytes()) for t in decode_tf(ref)]
    except Exception as err:  # noqa: BLE001 - a zero quaternion: the same refusal
        with pytest.raises(type(err), match=str(err)):
            decode_tf(got)
    else:
        assert [(t.stamp_ns, t.parent, t.child, t.pose.tobytes()) for t in decode_tf(got)] == want


@pytest.mark.parametrize("kind", ["ros1", "cdr"])
def test_tf_bytes_it_cannot_read_go_to_the_typestore(kind):
    """Damaged, longer than the standard layout, or big-endian: None, and the typestore reads (or reports) them."""
    raw = _tf_bytes(kind, [("base", "lidar"), ("base", "imu")], 1)
    assert parse_tf(raw, kind == "cdr") is not None
    assert parse_tf(raw[:-9], kind == "cdr") is None
    assert parse_tf(raw + bytes(8), kind == "cdr") is None
    assert parse_tf(_tf_bytes("cdr", [("base", "lidar")], 1, little_endian=False), True) is None
