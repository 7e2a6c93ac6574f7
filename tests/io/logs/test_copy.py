"""Copying a log's connections and messages: byte for byte where the output format holds the encoding."""

from pathlib import Path

import numpy as np
import pytest

from lio_cli.errors import InputError

from lio_cli.io.logs.reader import open_log
from lio_cli.io.logs.writer import LogWriter

SUFFIX = {"ros1": ".bag", "ros2": "", "ros2-mcap": "", "mcap": ".mcap"}


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
    copy = logs.copy_log(src, out, write_format)
    assert stored(out) == stored(src)
    assert connections(out) == connections(src)
    assert "/never_published" in {c[0] for c in connections(out)}
    assert copy.converted == {} and sum(copy.copied.values()) == len(stored(src))


@pytest.mark.parametrize("src_fmt,out_fmt", [("ros2", "mcap"), ("mcap", "ros2-mcap"), ("ros2-mcap", "ros2")])
def test_an_output_that_holds_the_encoding_copies_bytes_across_formats(logs, tmp_path, src_fmt, out_fmt):
    src = logs.sensor_log(src_fmt)
    out = tmp_path / f"copy{SUFFIX[out_fmt]}"
    logs.copy_log(src, out, out_fmt)
    strip = lambda rows: [r[:3] for r in rows]  # noqa: E731 - publish time/sequence exist in MCAP only
    assert strip(stored(out)) == strip(stored(src))


def test_ros1_encoded_mcap_becomes_ros2_profile_mcap_that_rosbags_reads(logs, tmp_path):
    """A ROS 1 profile MCAP copied as it was stayed unreadable to rosbags' AnyReader ("Profile is not ros2"):
    its channels are converted to CDR, a driver's own type from the schema the file stores."""
    from mcap.reader import make_reader

    src = logs.ros1_mcap(logs.sensor_log("ros1"), tmp_path / "ros1.mcap", packets=3)
    out = tmp_path / "out.mcap"
    copy = logs.copy_log(src, out, "mcap")
    assert copy.copied == {} and sum(copy.converted.values()) == len(stored(src))
    with out.open("rb") as f:
        assert make_reader(f).get_header().profile == "ros2"
    assert {c[2] for c in connections(out)} == {"cdr"}
    assert logs.anyreader_count(out) == len(stored(src))
    for topic in ("/packets", "/ground_truth", "/tf_static", "/odom"):
        assert logs.decoded(out, topic) == logs.decoded(src, topic)


def test_ros1_encoded_mcap_copies_into_a_ros1_bag_with_md5_from_its_schemas(logs, tmp_path):
    """An MCAP schema carries no md5, which a ROS 1 bag needs: it is computed from the stored definition (a
    driver's type too), so the copy stays byte for byte and the bag's md5 sums are what ROS 1 gives."""
    from rosbags.rosbag1 import Reader

    bag = logs.sensor_log("ros1")
    src = logs.ros1_mcap(bag, tmp_path / "ros1.mcap", packets=3)
    out = tmp_path / "out.bag"
    copy = logs.copy_log(src, out, "ros1")
    assert copy.converted == {} and stored(out) == [r[:3] + (None, None) for r in stored(src)]
    with Reader(bag) as a, Reader(out) as b:
        md5 = {c.topic: c.digest for c in a.connections}
        got = {c.topic: (c.digest, c.ext.callerid, c.ext.latching) for c in b.connections}
    assert got.pop("/packets")[0] and {t: d for t, (d, _, _) in got.items()} == md5
    assert got["/tf_static"][2] == 1  # latching from the channel metadata
    assert logs.anyreader_count(out) == len(stored(src))


def test_md5_sums_computed_for_a_real_ros1_mcap_are_its_recorders(logs, real_logs, tmp_path):
    """The recorder of a real ROS 1 MCAP noted each channel's md5 in its metadata: the sums lio computes from
    the schemas for a ROS 1 bag (ouster_ros/PacketMsg and rosgraph_msgs/Log among them) are those."""
    from mcap.reader import make_reader
    from rosbags.rosbag1 import Reader

    src = real_logs / "ouster_os1_ros1_mcap" / "os1_64.mcap"
    out = tmp_path / "os1.bag"
    logs.copy_log(src, out, "ros1")
    with src.open("rb") as f:
        noted = {(c.topic, c.metadata["md5sum"]) for c in make_reader(f).get_summary().channels.values()}
    with Reader(out) as r:
        assert {(c.topic, c.digest) for c in r.connections} == noted
    assert logs.anyreader_count(out) == len(stored(src))


@pytest.mark.parametrize("schema,what", [
    (b"this is not ] a definition\n", "the input's definition of lio_test/msg/Packet cannot be used (it uses "
                                      "lio_test/msg/this, which it does not define)"),
    (None, "the input stores no definition of unknown"),  # a channel without schema: its type unknown too
])
def test_a_type_without_a_usable_definition_is_refused_saying_what_is_missing(logs, tmp_path, schema, what):
    from mcap.writer import Writer

    src = tmp_path / "in.mcap"
    with src.open("wb") as f:
        w = Writer(f)
        w.start(profile="ros1", library="test")
        cid = w.register_channel("/packets", "ros1", w.register_schema("lio_test/Packet", "ros1msg", schema)
                                 if schema else 0, {})
        w.add_message(cid, log_time=1, publish_time=1, sequence=0, data=bytes(20))
        w.finish()
    for out, tail in ((tmp_path / "o.bag", " and it is not a standard type"),
                      (tmp_path / "o.mcap", " and it is not a standard message type, so lio cannot convert it from "
                                            "ros1 to cdr encoding; write a format that keeps ros1 instead (--format ros1)")):
        with pytest.raises(InputError) as err:
            logs.copy_log(src, out, "ros1" if out.suffix == ".bag" else "mcap")
        assert str(err.value).endswith(f"/packets: {what}{tail}") and not out.exists()


@pytest.mark.parametrize("out_fmt", ["ros1", "ros2", "mcap"])
def test_a_drivers_own_type_converts_from_its_stored_definition(logs, tmp_path, out_fmt):
    """It was refused ("the input stores no definition of ... and it is not a standard type") though the input
    stores it: ROS 1 bag -> ROS 2 / MCAP, and a CDR MCAP (no hash) -> ROS 2 bag (RIHS01 computed) or ROS 1."""
    bag = logs.sensor_log("ros1")
    ros1 = logs.ros1_mcap(bag, tmp_path / "ros1.mcap", packets=3)
    cdr = tmp_path / "cdr.mcap"
    logs.copy_log(ros1, cdr, "mcap")  # the driver's type as a CDR channel whose schema is the only definition
    for src in (ros1, cdr):
        out = tmp_path / f"{src.stem}_out{SUFFIX[out_fmt]}"
        logs.copy_log(src, out, out_fmt)
        assert logs.decoded(out, "/packets") == logs.decoded(ros1, "/packets")
        assert logs.anyreader_count(out) == len(stored(src))


def test_mcap_publish_times_and_sequence_numbers_are_kept(logs, tmp_path):
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
    logs.copy_log(src, out, "mcap")
    rows = stored(out)
    assert rows == stored(src)
    assert [r[3] for r in rows] == [10**9 * i + 123 for i in range(5)]
    assert [r[4] for r in rows] == [40 + 3 * i for i in range(5)]


def test_two_publishers_on_one_topic_stay_two_connections(logs, tmp_path):
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
    logs.copy_log(src, out, "ros1")
    assert stored(out) == stored(src)
    assert [(c[0], c[5], c[6]) for c in connections(out)] == [("/chatter", "/talker_a", None), ("/chatter", "/talker_b", 1)]


@pytest.mark.parametrize("src_fmt,out_fmt", [("ros1", "ros2"), ("ros1", "mcap"), ("ros2", "ros1"), ("mcap", "ros1")])
def test_ros1_and_ros2_bags_convert_field_for_field(logs, tmp_path, src_fmt, out_fmt):
    src = logs.sensor_log(src_fmt)
    out = tmp_path / f"copy{SUFFIX[out_fmt]}"
    copy = logs.copy_log(src, out, out_fmt)
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
    logs.copy_log(src, out, out_fmt)
    with AnyReader([out]) as r:
        qos = {c.topic: c.ext.offered_qos_profiles for c in r.connections}
    tf_static = qos["/tf_static"] if not isinstance(qos["/tf_static"], str) else parse_qos(qos["/tf_static"])
    assert [(q.durability, q.depth) for q in tf_static] == [(QosDurability.TRANSIENT_LOCAL, 1)]
    assert not qos["/imu"]  # not latched: no profile, as before
