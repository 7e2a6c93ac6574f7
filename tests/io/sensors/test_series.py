"""Whole topics as columns: the bulk byte decoder gives exactly what the typestore gives, in every format, and
hands a topic it cannot lay out to the typestore."""

from __future__ import annotations

import numpy as np
import pytest

from lio_cli.geometry import make_pose, so3_exp
from lio_cli.io.sensors import series
from lio_cli.io.logs.reader import open_log

T0 = 1_700_000_000 * 10**9


def _build(w) -> None:
    m = w.make
    w.add_topic("/imu", "sensor_msgs/msg/Imu")
    w.add_topic("/odom", "nav_msgs/msg/Odometry")
    w.add_topic("/twist", "geometry_msgs/msg/TwistStamped")
    w.add_topic("/pose", "geometry_msgs/msg/PoseStamped")
    rng = np.random.default_rng(4)
    for k in range(30):
        t = T0 + k * 10_000_000 + 123
        # accelerations around gravity in m/s^2 (read_series scales an IMU writing g: see test_imu_units)
        msg = m.imu(t, "imu_link" if k else "imu", rng.normal(size=3), rng.normal(size=3) + [0.0, 0.0, 9.81])
        msg.orientation = m.quaternion(rng.normal(size=4))
        msg.orientation_covariance = rng.normal(size=9)
        w.write("/imu", t + 1000, msg)
        T = make_pose(so3_exp(rng.normal(size=3)), rng.normal(size=3))
        od = m.odometry(t, "odom", "base_link", T, rng.normal(size=3), rng.normal(size=3))
        od.pose.covariance = rng.normal(size=36)
        od.twist.covariance = rng.normal(size=36)
        if k == 5:
            od.pose.pose.orientation = m.quaternion((0.0, 0.0, 0.0, 0.0))  # a twist-only driver
            od.twist.twist.linear.x = float("nan")
        w.write("/odom", t + 2000, od)
        w.write("/twist", t + 3000, m.twist_stamped(t, "base", rng.normal(size=3), rng.normal(size=3)))
        w.write("/pose", t + 4000, m.pose_stamped(t, "map", T))


def _same(a, b) -> None:
    for name, value in vars(a).items():
        other = getattr(b, name)
        if isinstance(value, np.ndarray):
            np.testing.assert_array_equal(value, other, err_msg=name)
        elif name != "frames":
            assert value == other, name


def test_bulk_decoding_equals_the_typestore_in_every_format(logs, write_format):
    path = logs.write(write_format, _build)
    with open_log(path) as log:
        cols = series.read_series(log, ["/imu", "/odom", "/twist", "/pose"])
        for topic, c in cols.items():
            _same(c, series._read_typestore(log, topic))
    imu, od, tw, pose = cols["/imu"], cols["/odom"], cols["/twist"], cols["/pose"]
    assert len(imu) == len(od) == len(tw) == len(pose) == 30
    assert imu.frames == ("imu", "imu_link") and imu.frame_id == "imu"
    assert imu.stamps_ns[3] == T0 + 30_000_123
    assert (od.frame_id, od.child_frame_id) == ("odom", "base_link")
    np.testing.assert_array_equal(od.quat_xyzw[5], [0.0, 0.0, 0.0, 0.0])
    assert np.isnan(od.linear_mps[5, 0])
    assert np.isnan(tw.position_m).all() and tw.pose_cov is None
    assert np.isnan(pose.linear_mps).all() and pose.frame_id == "map"


def test_a_topic_off_the_standard_layout_goes_through_the_typestore(logs, monkeypatch):
    path = logs.write("ros1", _build)
    calls = []
    original = series._read_typestore
    monkeypatch.setattr(series, "_read_typestore", lambda log, t: calls.append(t) or original(log, t))
    with open_log(path) as log:
        real = log.raw_messages

        def padded(topics):  # one Imu message a byte longer than its layout: another definition of the type
            for k, (t, mt, rec, raw) in enumerate(real(topics)):
                yield t, mt, rec, (bytes(raw) + b"\0" if t == "/imu" and k == 8 else raw)

        monkeypatch.setattr(log, "raw_messages", padded)
        whole = log.topic_messages

        def padded_whole(topics, *args):  # the same message, where the topics are read whole
            found = whole(topics, *args)
            found["/imu"][8] = bytes(found["/imu"][8]) + b"\0"
            return found

        monkeypatch.setattr(log, "topic_messages", padded_whole)
        cols = series.read_series(log, ["/imu", "/odom"])
    assert calls == ["/imu"]
    assert len(cols["/imu"]) == 30 and len(cols["/odom"]) == 30


def test_a_type_fuse_cannot_read_is_named(logs):
    def build(w):
        w.add_topic("/tf_static", "tf2_msgs/msg/TFMessage")
        w.write("/tf_static", T0, w.make.tf_message([]))

    path = logs.write("ros1", build)
    with open_log(path) as log, pytest.raises(Exception) as err:
        series.read_series(log, ["/tf_static"])
    assert str(err.value) == f"{path}: topic /tf_static is tf2_msgs/msg/TFMessage, which fuse cannot read"


def test_whole_topic_parse_equals_the_per_message_parse(logs, monkeypatch):
    path = logs.write("ros1", _build)
    with open_log(path) as log:
        fast = series.read_series(log, ["/imu", "/odom", "/twist"])
        monkeypatch.setattr(series._Bulk, "_add_uniform", lambda self, raws: False)
        slow = series.read_series(log, ["/imu", "/odom", "/twist"])
    for topic in fast:
        _same(fast[topic], slow[topic])
        assert getattr(fast[topic], "frames", None) == getattr(slow[topic], "frames", None)


@pytest.mark.parametrize("fmt, held", [("ros1", 30), ("mcap", 0), ("ros2", 0)])
def test_only_a_ros1_topic_is_held_for_the_whole_topic_parse(logs, monkeypatch, fmt, held):
    """CDR messages are parsed as they are read; holding them all would double a long log's memory for a parse
    only ROS 1's fixed layout allows."""
    path = logs.write(fmt, _build)
    seen: list[int] = []
    finish = series._Bulk.finish
    monkeypatch.setattr(series._Bulk, "finish", lambda self: (seen.append(len(self.raws)), finish(self))[1])
    with open_log(path) as log:
        imu = series.read_series(log, ["/imu"])["/imu"]
    assert seen == [held] and len(imu) == 30


def test_ros1_chunk_reader_yields_what_rosbags_yields(logs):
    path = logs.write("ros1", _build)
    with open_log(path) as log:
        topics = ["/imu", "/odom", "/pose"]
        ours = [(t, rec, bytes(raw)) for t, _, rec, raw in log.raw_messages(topics)]
        conns = [c for c in log._reader.connections if c.topic in topics]
        theirs = [(c.topic, int(rec), bytes(raw)) for c, rec, raw in log._reader.messages(connections=conns)]
    assert ours == theirs and len(ours) == 90


def test_ros1_chunk_reader_orders_equal_times_as_rosbags_does(tmp_path):
    # rosbags compares index entries by time only: equal times come connection by connection, each in its
    # index order, whatever order they were written in
    from rosbags.rosbag1 import Reader, Writer

    path = tmp_path / "ties.bag"
    with Writer(path) as w:
        a = w.add_connection("/a", "std_msgs/msg/String", msgdef="string data", md5sum="992ce8a1687cec8c8bd883ec73ca41d1")
        b = w.add_connection("/b", "std_msgs/msg/String", msgdef="string data", md5sum="992ce8a1687cec8c8bd883ec73ca41d1")
        for conn, t, text in ((b, 100, b"b1"), (a, 100, b"a1"), (a, 100, b"a2"), (b, 90, b"b0"), (a, 200, b"a3")):
            w.write(conn, t, len(text).to_bytes(4, "little") + text)
    with Reader(path) as r:
        theirs = [(c.topic, t, bytes(d)[4:]) for c, t, d in r.messages()]
    with open_log(path) as log:
        ours = [(rec.connection.topic, rec.log_time_ns, bytes(rec.data)[4:]) for rec in log.records()]
    assert ours == theirs == [("/b", 90, b"b0"), ("/a", 100, b"a1"), ("/a", 100, b"a2"), ("/b", 100, b"b1"),
                              ("/a", 200, b"a3")]


def test_ros1_chunk_reader_decompresses_each_chunk_once(tmp_path):
    # neighbouring chunks whose record times overlap: the time-ordered read goes back and forth between them,
    # and a peek at the first messages opens the chunk the full read opens next
    from rosbags.rosbag1 import Writer

    path = tmp_path / "overlap.bag"
    with Writer(path) as w:
        w.chunk_threshold = 64  # a few messages per chunk
        a = w.add_connection("/a", "std_msgs/msg/String", msgdef="string data", md5sum="992ce8a1687cec8c8bd883ec73ca41d1")
        for k in range(40):
            t = 100 * k + (150 if k % 4 == 3 else 0)  # every 4th message recorded late: into the next chunk's span
            w.write(a, t, (4).to_bytes(4, "little") + b"m%03d" % k)
    with open_log(path) as log:
        r = log._reader.readers[0]
        opened: list[int] = []
        for pos, chunk in list(r.chunks.items()):
            r.chunks[pos] = chunk._replace(decompressor=lambda raw, pos=pos, f=chunk.decompressor: (opened.append(pos),
                                                                                                   f(raw))[1])
        positions = sorted(r.chunks)
        assert len(positions) > 5
        first = next(iter(log.raw_messages(["/a"])))
        got = [bytes(raw)[4:] for _, _, _, raw in log.raw_messages(["/a"])]
        ours_opened = list(opened)
        theirs = [bytes(d)[4:] for _, _, d in log._reader.messages()]
    assert got == theirs and len(got) == 40 and bytes(first[3])[4:] == got[0]
    assert got != sorted(got)  # the record times did interleave the chunks
    assert sorted(ours_opened) == positions  # each chunk decompressed once


def test_ros1_chunk_reader_reads_rosbags_record_layout_without_the_field_walk(real_logs, monkeypatch):
    # ROS's own rosbag writes each message header as time, conn, op: the op is read at its place (the field
    # walk only for other layouts, such as the rosbags writer's), and the messages are rosbags' own
    from lio_cli.io.logs import bag1_raw

    walks = []
    op = bag1_raw._op
    monkeypatch.setattr(bag1_raw, "_op", lambda *a: walks.append(a[1]) or op(*a))
    with open_log(real_logs / "jackal_imu_wheel" / "jackal.bag") as log:
        ours = [(t, rec, bytes(raw)) for t, _, rec, raw in log.raw_messages()]
        theirs = [(c.topic, int(rec), bytes(raw)) for c, rec, raw in log._reader.messages()]
    assert ours == theirs and len(ours) > 6000
    assert walks == []


@pytest.mark.parametrize("name", ["jackal_imu_wheel/jackal.bag", "ardrone_twist_only/ardrone.bag"])
def test_ros1_topics_handed_over_whole_are_what_the_chunk_reader_yields(real_logs, name):
    # rosbag's own record layout: each topic's messages sliced chunk by chunk, each chunk decompressed once
    with open_log(real_logs / name) as log:
        conns = log._reader.connections
        topics = [t for t in log.topics if sum(c.topic == t for c in conns) == 1]
        r = log._reader.readers[0]
        opened: list[int] = []
        for pos, chunk in list(r.chunks.items()):
            r.chunks[pos] = chunk._replace(decompressor=lambda raw, pos=pos, f=chunk.decompressor: (opened.append(pos),
                                                                                                   f(raw))[1])
        counts: list[int] = []
        whole = log.topic_messages(topics, counts.append)
        streamed: dict[str, list[bytes]] = {t: [] for t in topics}
        for t, _, _, raw in log.raw_messages(topics):
            streamed[t].append(bytes(raw))
    assert whole is not None and {t: [bytes(m) for m in v] for t, v in whole.items()} == streamed
    assert sum(map(len, streamed.values())) > 6000
    assert sorted(opened[:len(r.chunks)]) == sorted(r.chunks)  # the whole-topic read: each chunk once
    # progress after every chunk that holds any of the topics, up to all their messages
    assert len(counts) > 1 and counts == sorted(counts) and counts[-1] == sum(map(len, streamed.values()))


def test_ros1_topics_in_rosbags_record_layout_are_read_whole_and_other_formats_streamed(logs):
    # the rosbags writer puts a message header's op field first: topic_messages reads it whole as it does
    # rosbag's layout (bag1_raw._LAYOUTS), the same bytes as streaming; a log of another format never hands topics
    # over whole, and read_series streams it
    for fmt in ("ros1", "mcap"):
        path = logs.write(fmt, _build)
        with open_log(path) as log:
            whole = log.topic_messages(["/imu", "/odom"])
            streamed: dict[str, list[bytes]] = {"/imu": [], "/odom": []}
            for t, _, _, raw in log.raw_messages(["/imu", "/odom"]):
                streamed[t].append(bytes(raw))
            imu = series.read_series(log, ["/imu"])["/imu"]
        if fmt == "ros1":
            assert {t: [bytes(m) for m in v] for t, v in whole.items()} == streamed
        else:
            assert whole is None
        assert len(imu) == 30 and len(streamed["/imu"]) == 30
