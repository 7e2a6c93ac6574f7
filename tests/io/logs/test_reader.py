"""open_log: format detection, every format, split bags, third-party logs, spans and counts, bad files."""

from __future__ import annotations

import shutil

import numpy as np
import pytest

from lio_cli.errors import InputError
from lio_cli.io.logs.detect import detect_format
from lio_cli.io.logs.reader import open_log

POINTS_PER_SCAN = 52


def read_all(path, fmt=None):
    with open_log(path, fmt) as log:
        return log.format, [(topic, t) for topic, _, t, _ in log.messages()], dict(log.topics)


def test_every_written_format_reads_back_in_record_time_order(logs, write_format):
    path = logs.sensor_log(write_format, duration_s=0.5)
    with open_log(path) as log:
        assert log.format == logs.READ_FORMAT[write_format]
        counts = {name: t.count for name, t in log.topics.items()}
        assert counts == {"/tf_static": 1, "/points": 5, "/imu": 50, "/odom": 10, "/ground_truth": 5}
        assert log.topics["/imu"].msgtype == "sensor_msgs/msg/Imu"
        assert log.topics["/points"].msgtype == "sensor_msgs/msg/PointCloud2"
        times = [t for _, _, t, _ in log.raw_messages()]
        assert times == sorted(times) and len(times) == 71
        assert log.start_ns == logs.T0_NS  # /tf_static
        assert log.end_ns == times[-1]
        msgs = list(log.messages(["/points"]))
        assert len(msgs) == 5 and all(m[3].header.frame_id == "velodyne" for m in msgs)


def test_topic_spans_give_true_rates(logs, write_format):
    path = logs.sensor_log(write_format, duration_s=1.0)
    with open_log(path) as log:
        imu = log.topics["/imu"]
        assert (imu.first_ns, imu.last_ns) == (logs.T0_NS + 1000, logs.T0_NS + 990_000_000 + 1000)
        assert imu.rate_hz == pytest.approx(100.0)
        assert log.topics["/points"].rate_hz == pytest.approx(10.0)
        assert log.topics["/tf_static"].rate_hz is None


def test_ros2_bag_opens_from_folder_metadata_and_storage_file(logs):
    for fmt, storage in (("ros2", ".db3"), ("ros2-mcap", ".mcap")):
        path = logs.sensor_log(fmt, duration_s=0.2)
        files = sorted(p.name for p in path.iterdir())
        assert files == sorted(["metadata.yaml", path.name + storage])  # no stray temp names
        for p in (path, path / "metadata.yaml", path / (path.name + storage)):
            fmt_read, msgs, _ = read_all(p)
            assert fmt_read == "ros2" and len(msgs) == 1 + 2 + 20 + 4 + 2


def test_folder_of_split_ros1_bags_is_replayed_in_time_order(logs, tmp_path):
    folder = tmp_path / "split"
    folder.mkdir()

    def part(parity):
        def build(w):
            w.add_topic("/imu", "sensor_msgs/msg/Imu")
            for i in range(parity, 20, 2):
                t = logs.T0_NS + i * 10_000_000
                w.write("/imu", t, w.make.imu(t, "imu", [i, 0, 0], [0, 0, 9.81]))
        return build

    # names sort opposite to time: a plain concatenation would come out of order
    logs.write("ros1", part(1), name="split/a_odd")
    logs.write("ros1", part(0), name="split/b_even")
    assert detect_format(folder) == ("ros1", [folder / "a_odd.bag", folder / "b_even.bag"])
    with open_log(folder) as log:
        assert log.topics["/imu"].count == 20
        gyro_x = [m.angular_velocity.x for _, _, _, m in log.messages()]
        stamps = [t for _, _, t, _ in log.raw_messages()]
    assert gyro_x == list(range(20))
    assert stamps == [logs.T0_NS + i * 10_000_000 for i in range(20)]


def test_logs_written_by_rosbags_writers_directly_are_read(tmp_path):
    from rosbags.rosbag1 import Writer as Writer1
    from rosbags.rosbag2 import Writer as Writer2
    from rosbags.typesys import Stores, get_typestore

    for store, path, Writer in ((Stores.ROS1_NOETIC, tmp_path / "third.bag", Writer1),
                                (Stores.ROS2_HUMBLE, tmp_path / "third_ros2", Writer2)):
        ts = get_typestore(store)
        T = ts.types
        ros1 = store == Stores.ROS1_NOETIC
        hdr = (lambda ns: T["std_msgs/msg/Header"](seq=0, stamp=T["builtin_interfaces/msg/Time"](sec=ns // 10**9, nanosec=ns % 10**9), frame_id="imu")) if ros1 else \
            (lambda ns: T["std_msgs/msg/Header"](stamp=T["builtin_interfaces/msg/Time"](sec=ns // 10**9, nanosec=ns % 10**9), frame_id="imu"))
        V = T["geometry_msgs/msg/Vector3"]
        kw = {} if ros1 else {"version": 8}
        with Writer(path, **kw) as w:
            conn = w.add_connection("/imu/data", "sensor_msgs/msg/Imu", typestore=ts)
            for i in range(5):
                ns = 1_600_000_000 * 10**9 + i * 5_000_000
                msg = T["sensor_msgs/msg/Imu"](
                    header=hdr(ns), orientation=T["geometry_msgs/msg/Quaternion"](x=0.0, y=0.0, z=0.0, w=1.0),
                    orientation_covariance=np.zeros(9), angular_velocity=V(x=0.0, y=0.0, z=float(i)),
                    angular_velocity_covariance=np.zeros(9), linear_acceleration=V(x=0.0, y=0.0, z=9.8),
                    linear_acceleration_covariance=np.zeros(9))
                data = ts.serialize_ros1(msg, "sensor_msgs/msg/Imu") if ros1 else ts.serialize_cdr(msg, "sensor_msgs/msg/Imu")
                w.write(conn, ns, data)
        with open_log(path) as log:
            assert log.format == ("ros1" if ros1 else "ros2")
            assert [m.angular_velocity.z for _, _, _, m in log.messages()] == [0.0, 1.0, 2.0, 3.0, 4.0]


def test_format_override(logs, tmp_path):
    bag = logs.sensor_log("ros1", duration_s=0.2)
    renamed = tmp_path / "recording.dat"  # no .bag suffix: recognised by content, or forced
    shutil.copy(bag, renamed)
    for fmt in (None, "ros1"):
        fmt_read, msgs, _ = read_all(renamed, fmt)
        assert fmt_read == "ros1" and len(msgs) == 29
    # a ROS 2 bag's mcap storage file read as a bare MCAP file
    ros2 = logs.sensor_log("ros2-mcap", duration_s=0.2)
    fmt_read, msgs, topics = read_all(ros2 / (ros2.name + ".mcap"), "mcap")
    assert fmt_read == "mcap" and len(msgs) == 29 and topics["/imu"].count == 20
    with pytest.raises(InputError, match=r"unknown log format 'ros3' \(choose from ros1, ros2, mcap\)"):
        open_log(bag, "ros3")
    # a format the content contradicts: said so (it read "cannot open as MCAP ... truncated or corrupted")
    asked = ("as asked (--format, --input-format or input.format in --config; a .config.yaml written before this "
             "release pins the format it found: make it null)")
    for fmt, name in (("ros2", "a ROS 2 bag"), ("mcap", "an MCAP file")):
        with pytest.raises(InputError) as err:
            open_log(bag, fmt)
        assert str(err.value) == f"{bag}: is a ROS 1 bag, not {name} {asked}"
    with pytest.raises(InputError) as err:
        open_log(ros2, "ros1")
    assert str(err.value) == f"{ros2}: is a ROS 2 bag, not a ROS 1 bag {asked}"


def test_detect_format_rejects_what_is_not_a_log(tmp_path):
    (tmp_path / "notes.txt").write_text("not a log\n")
    (tmp_path / "empty.bag").write_bytes(b"")
    (tmp_path / "folder").mkdir()
    with pytest.raises(InputError, match="no such file or folder"):
        detect_format(tmp_path / "missing.bag")
    with pytest.raises(InputError, match="not a ROS 1 bag, ROS 2 bag or MCAP file"):
        detect_format(tmp_path / "notes.txt")
    with pytest.raises(InputError, match="file is empty, not a log"):
        detect_format(tmp_path / "empty.bag")
    with pytest.raises(InputError, match="folder holds no log"):
        detect_format(tmp_path / "folder")


@pytest.mark.parametrize("fmt", ["ros1", "mcap", "ros2-mcap"])
def test_truncated_log_is_input_error_at_open_or_read(logs, fmt):
    path = logs.sensor_log(fmt, duration_s=0.5)
    target = path / (path.name + ".mcap") if fmt == "ros2-mcap" else path
    data = target.read_bytes()
    target.write_bytes(data[: len(data) // 2])
    with pytest.raises(InputError, match="truncated or corrupted"):
        with open_log(path) as log:
            list(log.raw_messages())


def test_corrupt_record_header_in_ros1_bag_fails_on_read(logs):
    path = logs.sensor_log("ros1", duration_s=0.5)
    data = bytearray(path.read_bytes())
    # turn the op code of a message-data record in the middle of the file into garbage
    pos = data.find(b"op=\x02", len(data) // 3)
    assert pos > 0
    data[pos + 3] = 0x7F
    path.write_bytes(bytes(data))
    with open_log(path) as log:  # the index at the end is intact
        with pytest.raises(InputError, match=rf"^{path}: cannot read messages \(.*\); the log may be truncated or corrupted$"):
            list(log.raw_messages())


def test_corrupt_chunk_in_mcap_fails_crc_on_read(logs):
    path = logs.sensor_log("mcap", duration_s=0.5)
    from mcap.reader import make_reader

    with path.open("rb") as f:
        chunk = make_reader(f).get_summary().chunk_indexes[0]
    data = bytearray(path.read_bytes())
    mid = chunk.chunk_start_offset + chunk.chunk_length // 2
    data[mid : mid + 16] = bytes(16)  # zeros inside the compressed chunk
    path.write_bytes(bytes(data))
    with open_log(path) as log:
        with pytest.raises(InputError, match="truncated or corrupted"):
            list(log.raw_messages())


def test_empty_log_opens_with_no_messages(logs, write_format):
    path = logs.write(write_format, lambda w: w.add_topic("/imu", "sensor_msgs/msg/Imu"))
    with open_log(path) as log:
        assert log.topics["/imu"].count == 0 and log.topics["/imu"].rate_hz is None
        assert list(log.messages()) == []
        assert log.duration_ns == 0


def test_ros2_bag_without_stored_definitions_uses_the_standard_ones(logs):
    import sqlite3

    path = logs.sensor_log("ros2", duration_s=0.2)
    con = sqlite3.connect(path / f"{path.name}.db3")  # as bags recorded before definitions were stored
    con.execute("DELETE FROM message_definitions")
    con.commit()
    con.close()
    with open_log(path) as log:
        imu = [m for _, _, _, m in log.messages(["/imu"])]
    assert len(imu) == 20 and imu[0].linear_acceleration.z == 9.81
