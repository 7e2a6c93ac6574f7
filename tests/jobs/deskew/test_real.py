"""``lio deskew`` on real recordings: drivers' own cloud layouts and clocks, not the simulator's.

Each of these logs holds two to five scans, too few to judge accuracy; what they check is that the rules hold
on layouts nobody here designed: other topics byte for byte, clouds of the same layout, count and order, a
readable output, and a clear refusal where a rule cannot hold.
"""

from __future__ import annotations

import numpy as np

from lio_cli.cli.app import main
from lio_cli.io.messages.pointcloud import cloud_dtype, stamp_to_ns
from lio_cli.io.logs.reader import open_log


def _records(path, skip: str) -> list:
    with open_log(path) as r:
        return [(x.connection.topic, x.log_time_ns, bytes(x.data)) for x in r.records() if x.connection.topic != skip]


def _clouds(path, topic: str) -> list:
    with open_log(path) as r:
        return [r.deserialize(x) for x in r.records([topic])]


def test_ouster_unsigned_point_times_refuse_the_end_reference_and_take_the_start(real_logs, tmp_path, capsys):
    """A ROS 1 encoded MCAP (mcap's ros1 profile) written as a ROS 1 bag: byte for byte, the md5 sums from its
    schemas (it was refused: "the input stores no definition of ouster_ros/msg/PacketMsg")."""
    log = real_logs / "ouster_os1_ros1_mcap" / "os1_64.mcap"
    out = tmp_path / "os1.bag"
    assert main(["deskew", str(log), str(out), "-q", "--motion", "constant-velocity"]) == 2
    assert capsys.readouterr().err.strip() == (
        f"lio: error: {log}: /os1_cloud_node/points: the per-point time field 't' is unsigned, so it cannot hold "
        "the negative offsets of --reference end (every point before the new header stamp); use --reference start")
    assert not out.exists()
    assert main(["deskew", str(log), str(out), "-q", "--motion", "constant-velocity", "--reference", "start"]) == 0
    topic = "/os1_cloud_node/points"
    assert _records(out, topic) == _records(log, topic)  # images, packets, IMU, /tf_static: byte for byte
    raw, new = _clouds(log, topic), _clouds(out, topic)
    assert len(raw) == len(new) == 2
    for a, b in zip(raw, new):
        assert (a.height, a.width, a.point_step, a.header.frame_id) == (b.height, b.width, b.point_step, b.header.frame_id)
        va = np.frombuffer(np.asarray(a.data).tobytes(), dtype=cloud_dtype(a))
        vb = np.frombuffer(np.asarray(b.data).tobytes(), dtype=cloud_dtype(b))
        for name in va.dtype.names:
            if name not in ("x", "y", "z", "t"):
                np.testing.assert_array_equal(vb[name], va[name])
        # header + t keeps every point's capture time; the header moved to the first valid point, and the
        # invalid points before it, which an unsigned field cannot put earlier, are held at zero
        shift = stamp_to_ns(b.header.stamp) - stamp_to_ns(a.header.stamp)
        assert shift > 0
        expected = np.maximum(va["t"].astype(np.int64) - shift, 0)
        np.testing.assert_array_equal(vb["t"].astype(np.int64), expected)
        valid = np.isfinite(va["x"]) & ((va["x"] != 0) | (va["y"] != 0) | (va["z"] != 0))
        assert (va["t"][valid].astype(np.int64) >= shift).all()  # no valid point was clamped
    assert main(["info", str(out), "--check", "-q"]) == 0


def test_a_ros1_encoded_mcap_written_as_mcap_or_ros2_is_converted_and_rosbags_reads_it(real_logs, tmp_path,
                                                                                       log_tools):
    """It kept the ros1 profile, which rosbags' AnyReader refuses, and a ROS 2 output refused /rosout
    (rosgraph_msgs/Log is no ROS 2 type): the driver's and ROS 1's own types convert from the file's schemas."""
    log = real_logs / "ouster_os1_ros1_mcap" / "os1_64.mcap"
    for out, fmt in ((tmp_path / "os1.mcap", "mcap"), (tmp_path / "os1_ros2", "ros2")):
        assert main(["deskew", str(log), str(out), "-q", "--motion", "constant-velocity", "--reference", "start",
                     "--format", fmt]) == 0
        assert log_tools.anyreader_count(out) == 273
        for topic in ("/rosout", "/os1_node/imu_packets", "/tf_static"):
            assert log_tools.decoded(out, topic) == log_tools.decoded(log, topic)


def test_luminar_absolute_split_point_times_stay_and_the_points_move_with_the_truck(real_logs, tmp_path):
    log = real_logs / "luminar_truck" / "luminar.bag"
    out = tmp_path / "lum.bag"
    topic = "/luminar_pointcloud"
    assert main(["deskew", str(log), str(out), "-q", "--lidar-topic", topic, "--motion", "constant-velocity"]) == 0
    assert _records(out, topic) == _records(log, topic)
    moved = []
    for a, b in zip(_clouds(log, topic), _clouds(out, topic), strict=True):
        va = np.frombuffer(np.asarray(a.data).tobytes(), dtype=cloud_dtype(a))
        vb = np.frombuffer(np.asarray(b.data).tobytes(), dtype=cloud_dtype(b))
        for name in ("time_sec", "time_nsec", "intensity"):  # absolute times stay as they are
            np.testing.assert_array_equal(vb[name], va[name])
        ok = np.isfinite(va["x"])
        moved.append(np.median(np.hypot(vb["x"][ok] - va["x"][ok], vb["y"][ok] - va["y"][ok])))
    # a truck at ~23 m/s: a point recorded half a sweep (tens of ms) before the end moves by decimetres to metres
    assert 0.1 < np.median(moved) < 5.0
    assert main(["info", str(out), "--check", "-q"]) == 0
