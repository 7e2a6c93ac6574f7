"""LogWriter: every format round-trips, outputs are atomic, never clobbered without force."""

from __future__ import annotations

import numpy as np
import pytest

from lio_cli.errors import InputError
from lio_cli.io.logs.reader import open_log
from lio_cli.io.logs.writer import LogWriter


def test_round_trip_every_format(tmp_path, write_format, logs):
    path = logs.path(write_format, "rt")
    arr, offsets = logs.velodyne_cloud(16)
    with LogWriter(path, write_format) as w:
        w.add_topic("/points", "sensor_msgs/msg/PointCloud2")
        w.add_topic("/points", "sensor_msgs/msg/PointCloud2")  # adding twice is harmless
        w.write("/points", logs.T0_NS, w.make.pointcloud2(logs.T0_NS, "lidar", arr))
        w.write_raw("/points", logs.T0_NS + 1, w.serialize(w.make.pointcloud2(logs.T0_NS + 1, "lidar", arr),
                                                           "sensor_msgs/msg/PointCloud2"))
    with open_log(path) as log:
        msgs = list(log.messages())
    assert [t for _, _, t, _ in msgs] == [logs.T0_NS, logs.T0_NS + 1]
    data = np.frombuffer(bytes(msgs[0][3].data), dtype=arr.dtype)
    np.testing.assert_array_equal(data, arr)
    assert not [p for p in tmp_path.iterdir() if p.name.startswith(".")]  # no temp left behind


def test_existing_output_needs_force(logs, write_format):
    path = logs.sensor_log(write_format, duration_s=0.1)
    with pytest.raises(InputError, match="already exists; pass --force to overwrite it"):
        LogWriter(path, write_format)
    with LogWriter(path, write_format, force=True) as w:
        w.add_topic("/only", "sensor_msgs/msg/Imu")
    with open_log(path) as log:
        assert list(log.topics) == ["/only"]


def test_error_inside_with_leaves_nothing_and_keeps_old_output(logs, tmp_path):
    path = logs.sensor_log("ros2", duration_s=0.1)
    before = sorted(p.name for p in path.iterdir())
    with pytest.raises(RuntimeError):
        with LogWriter(path, "ros2", force=True) as w:
            w.add_topic("/x", "sensor_msgs/msg/Imu")
            raise RuntimeError("boom")
    assert sorted(p.name for p in path.iterdir()) == before
    assert sorted(p.name for p in tmp_path.iterdir()) == [path.name]


def test_bad_format_and_missing_folder(tmp_path):
    with pytest.raises(InputError, match=r"unknown output format 'bag' \(choose from ros1, ros2, ros2-mcap, mcap\)"):
        LogWriter(tmp_path / "x.bag", "bag")
    with pytest.raises(InputError, match="output folder does not exist"):
        LogWriter(tmp_path / "nope" / "x.bag", "ros1")


def test_finish_then_commit_and_the_temporary_named_before_it_exists(tmp_path, write_format, logs):
    """finish() writes the log's end into its temporary (nothing in place yet), commit() renames it; the
    temporary (a ROS 2 bag's folder) is named to ``on_temp`` before it is created."""
    path = logs.path(write_format, "fc")
    named = []
    w = LogWriter(path, write_format, on_temp=lambda p: named.append((p, p.exists())))
    assert named == [(w.temp_path, False)] and w.temp_path.exists()
    w.add_topic("/imu", "sensor_msgs/msg/Imu")
    w.finish()
    assert w.temp_path.exists() and not path.exists()
    w.commit()
    assert path.exists() and not w.temp_path.exists()
    with open_log(path) as log:
        assert list(log.topics) == ["/imu"]
    assert not [p for p in tmp_path.iterdir() if p.name.startswith(".")]


def test_an_interrupt_while_finishing_leaves_no_temporary(tmp_path, monkeypatch):
    w = LogWriter(tmp_path / "x.bag", "ros1")
    w.add_topic("/imu", "sensor_msgs/msg/Imu")
    monkeypatch.setattr(w._w, "close", lambda: (_ for _ in ()).throw(KeyboardInterrupt))
    with pytest.raises(KeyboardInterrupt):
        w.finish()
    assert list(tmp_path.iterdir()) == []
