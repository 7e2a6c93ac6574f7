"""Copying a log's connections and messages: byte for byte where the output format holds the encoding."""

from pathlib import Path

import numpy as np
import pytest

from lio_cli.io.log_copy import LogCopy, mcap_profile
from lio_cli.io.reader import open_log
from lio_cli.io.writer import LogWriter

SUFFIX = {"ros1": ".bag", "ros2": "", "ros2-mcap": "", "mcap": ".mcap"}


def copy_all(src: Path, out: Path, fmt: str) -> LogCopy:
    with open_log(src) as r, LogWriter(out, fmt, mcap_profile=mcap_profile(r)) as w:
        copy = LogCopy(r, w)
        copy.mirror_all()
        for rec in r.records():
            copy.copy(rec)
    return copy


def stored(path: Path) -> list[tuple]:
    with open_log(path) as r:
        return sorted((x.connection.topic, x.log_time_ns, bytes(x.data), x.publish_time_ns, x.sequence)
                      for x in r.records())


def connections(path: Path) -> list[tuple]:
    with open_log(path) as r:
        return sorted((c.topic, c.msgtype, c.encoding, c.msgdef, c.digest, c.callerid, c.latching, c.metadata)
                      for c in r.connections)


def test_same_format_copy_is_byte_identical_with_connections_and_empty_topics(logs, write_format, tmp_path):
    src = logs.sensor_log(write_format, extra=lambda w: w.add_topic("/never_published", "sensor_msgs/msg/Imu"))
    out = tmp_path / f"copy{SUFFIX[write_format]}"
    copy = copy_all(src, out, write_format)
    assert stored(out) == stored(src)
    assert connections(out) == connections(src)
    assert "/never_published" in {c[0] for c in connections(out)}
    assert copy.converted == {} and sum(copy.copied.values()) == len(stored(src))


@pytest.mark.parametrize("src_fmt,out_fmt", [("ros2", "mcap"), ("mcap", "ros2-mcap"), ("ros2-mcap", "ros2")])
def test_an_output_that_holds_the_encoding_copies_bytes_across_formats(logs, tmp_path, src_fmt, out_fmt):
    src = logs.sensor_log(src_fmt)
    out = tmp_path / f"copy{SUFFIX[out_fmt]}"
    copy_all(src, out, out_fmt)
    strip = lambda rows: [r[:3] for r in rows]  # noqa: E731 - publish time/sequence exist in MCAP only
    assert strip(stored(out)) == strip(stored(src))


def test_ros1_encoded_mcap_stays_ros1_encoded(logs, tmp_path):
    """An MCAP file with ROS 1 channels (mcap's ros1 profile) is copied as it is: encoding, profile, metadata."""
    from mcap.reader import make_reader
    from mcap.writer import Writer
    from rosbags.typesys import Stores, get_typestore

    ts = get_typestore(Stores.ROS1_NOETIC)
    msgdef, _ = ts.generate_msgdef("std_msgs/msg/String")
    src = tmp_path / "ros1.mcap"
    with src.open("wb") as f:
        w = Writer(f)
        w.start(profile="ros1", library="test")
        sid = w.register_schema("std_msgs/String", "ros1msg", msgdef.encode())
        cid = w.register_channel("/chatter", "ros1", sid, metadata={"callerid": "/talker", "latching": "1"})
        for i in range(3):
            w.add_message(cid, log_time=100 + i, publish_time=90 + i, sequence=i,
                          data=bytes(ts.serialize_ros1(ts.types["std_msgs/msg/String"](data=f"m{i}"), "std_msgs/msg/String")))
        w.finish()
    out = tmp_path / "out.mcap"
    copy = copy_all(src, out, "mcap")
    assert stored(out) == stored(src) and copy.converted == {}
    assert connections(out) == connections(src)
    with out.open("rb") as f:
        assert make_reader(f).get_header().profile == "ros1"


def test_mcap_publish_times_and_sequence_numbers_are_kept(tmp_path):
    from mcap.writer import Writer
    from rosbags.typesys import Stores, get_typestore

    ts = get_typestore(Stores.ROS2_HUMBLE)
    Imu = ts.types["sensor_msgs/msg/Imu"]
    src = tmp_path / "in.mcap"
    msgdef, _ = ts.generate_msgdef("sensor_msgs/msg/Imu", ros_version=2)
    with src.open("wb") as f:
        w = Writer(f)
        w.start(profile="ros2", library="test")
        sid = w.register_schema("sensor_msgs/msg/Imu", "ros2msg", msgdef.encode())
        cid = w.register_channel("/imu", "cdr", sid, metadata={"offered_qos_profiles": ""})
        for i in range(5):
            m = Imu(header=ts.types["std_msgs/msg/Header"](stamp=ts.types["builtin_interfaces/msg/Time"](sec=i, nanosec=7),
                                                             frame_id="imu"),
                    orientation=ts.types["geometry_msgs/msg/Quaternion"](x=0.0, y=0.0, z=0.0, w=1.0),
                    orientation_covariance=np.zeros(9), angular_velocity=ts.types["geometry_msgs/msg/Vector3"](x=i, y=0.0, z=0.0),
                    angular_velocity_covariance=np.zeros(9),
                    linear_acceleration=ts.types["geometry_msgs/msg/Vector3"](x=0.0, y=0.0, z=9.81),
                    linear_acceleration_covariance=np.zeros(9))
            w.add_message(cid, log_time=10**9 * i + 500, publish_time=10**9 * i + 123, sequence=40 + 3 * i,
                          data=bytes(ts.serialize_cdr(m, "sensor_msgs/msg/Imu")))
        w.finish()
    out = tmp_path / "out.mcap"
    copy_all(src, out, "mcap")
    rows = stored(out)
    assert rows == stored(src)
    assert [r[3] for r in rows] == [10**9 * i + 123 for i in range(5)]
    assert [r[4] for r in rows] == [40 + 3 * i for i in range(5)]


def test_two_publishers_on_one_topic_stay_two_connections(tmp_path):
    from rosbags.rosbag1 import Writer
    from rosbags.typesys import Stores, get_typestore

    ts = get_typestore(Stores.ROS1_NOETIC)
    String = ts.types["std_msgs/msg/String"]
    src = tmp_path / "in.bag"
    with Writer(src) as w:
        a = w.add_connection("/chatter", "std_msgs/msg/String", typestore=ts, callerid="/talker_a")
        b = w.add_connection("/chatter", "std_msgs/msg/String", typestore=ts, callerid="/talker_b", latching=1)
        w.write(a, 10, bytes(ts.serialize_ros1(String(data="from a"), "std_msgs/msg/String")))
        w.write(b, 20, bytes(ts.serialize_ros1(String(data="from b"), "std_msgs/msg/String")))
    out = tmp_path / "out.bag"
    copy_all(src, out, "ros1")
    assert stored(out) == stored(src)
    assert [(c[0], c[5], c[6]) for c in connections(out)] == [("/chatter", "/talker_a", None), ("/chatter", "/talker_b", 1)]


@pytest.mark.parametrize("src_fmt,out_fmt", [("ros1", "ros2"), ("ros1", "mcap"), ("ros2", "ros1"), ("mcap", "ros1")])
def test_ros1_and_ros2_bags_convert_field_for_field(logs, tmp_path, src_fmt, out_fmt):
    src = logs.sensor_log(src_fmt)
    out = tmp_path / f"copy{SUFFIX[out_fmt]}"
    copy = copy_all(src, out, out_fmt)
    assert copy.copied == {} and sum(copy.converted.values()) == len(stored(src))

    def content(path):
        with open_log(path) as r:
            imu = [(t, m.stamp_ns, m.gyro_radps, m.accel_mps2) for _, _, t, m in r.messages(["/imu"], fast=True)]
            gt = [(t, m.header.frame_id, m.pose.position.x) for _, _, t, m in r.messages(["/ground_truth"])]
            tf = [[(x.header.frame_id, x.child_frame_id, x.transform.translation.y) for x in m.transforms]
                  for _, _, _, m in r.messages(["/tf_static"])]
            pts = [bytes(m.data) for _, _, _, m in r.messages(["/points"], fast=True)]
        return imu, gt, tf, pts

    assert content(out) == content(src)


@pytest.mark.parametrize("out_fmt", ["ros2", "mcap"])
def test_a_latched_ros1_topic_becomes_transient_local_in_ros2(logs, tmp_path, out_fmt):
    """/tf_static latched in ROS 1 came out of a conversion with an empty QoS profile, which a ROS 2 player offers
    volatile: a node started after the first message never got the extrinsics."""
    from rosbags.highlevel import AnyReader
    from rosbags.interfaces import QosDurability
    from rosbags.rosbag2.metadata import parse_qos

    src = logs.sensor_log("ros1")  # /tf_static written latched
    out = tmp_path / f"copy{SUFFIX[out_fmt]}"
    copy_all(src, out, out_fmt)
    with AnyReader([out]) as r:
        qos = {c.topic: c.ext.offered_qos_profiles for c in r.connections}
    tf_static = qos["/tf_static"] if not isinstance(qos["/tf_static"], str) else parse_qos(qos["/tf_static"])
    assert [(q.durability, q.depth) for q in tf_static] == [(QosDurability.TRANSIENT_LOCAL, 1)]
    assert not qos["/imu"]  # not latched: no profile, as before
