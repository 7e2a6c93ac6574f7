"""Rewriting a cloud in its own bytes: only x/y/z of valid points, the stamp and the time field change."""

import numpy as np
import pytest

from lio_cli.io.messages.cloud_rewrite import (deskewed_data, laserscan_cloud, patch_pointcloud2, points_view, shift_time_field,
                                      valid_mask)
from lio_cli.io.messages.pointcloud import NAMED_CONVENTIONS, decode_pointcloud2, detect_time_convention
from lio_cli.io.messages.rawmsg import parse_pointcloud2
from lio_cli.io.logs.writer import LogWriter
from lio_cli.model.records import TimeConvention

T0 = 1_700_000_000 * 10**9 + 123_456_789
FLOAT32_TIME_NS = 8  # one float32 ulp of a 0.1 s offset is 7.5 ns


def _padded_cloud(n_rows=3, width=7):
    """Velodyne-like points with a float time, an unnamed 2-byte gap inside each point and 5 bytes of row padding."""
    dt = np.dtype({"names": ["x", "y", "z", "intensity", "ring", "time"],
                   "formats": ["<f4", "<f4", "<f4", "<f4", "<u2", "<f4"],
                   "offsets": [0, 4, 8, 12, 16, 20], "itemsize": 24})
    rng = np.random.default_rng(0)
    arr = np.zeros(n_rows * width, dtype=dt)
    arr["x"], arr["y"], arr["z"] = rng.normal(size=(3, n_rows * width)) * 5
    arr["intensity"] = np.arange(n_rows * width)
    arr["ring"] = np.arange(n_rows * width) % 16
    arr["time"] = np.arange(n_rows * width) * 1e-3
    arr["x"][[2, 9]] = np.nan  # invalid returns
    arr["x"][4] = arr["y"][4] = arr["z"][4] = 0.0
    arr["time"][11] = np.nan  # a point without time
    return arr, dt


def _serialised(fmt, arr, dt, n_rows, width, tmp_path):
    """One PointCloud2 written by rosbags with row padding and garbage in every gap, read back as bytes."""
    w = LogWriter(tmp_path / f"c{fmt}.bag", fmt)
    try:
        row_step = width * dt.itemsize + 5
        data = np.frombuffer(np.random.default_rng(1).bytes(n_rows * row_step), dtype=np.uint8).copy()
        for r in range(n_rows):
            row = np.frombuffer(arr[r * width:(r + 1) * width].tobytes(), dtype=np.uint8).copy()
            gap = np.ones(dt.itemsize, bool)
            for name in dt.names:
                off, size = dt.fields[name][1], dt.fields[name][0].itemsize
                gap[off:off + size] = False
            row.reshape(width, dt.itemsize)[:, gap] = 0xAB  # the gap holds bytes of its own
            data[r * row_step:r * row_step + len(row)] = row
        msg = w.make.pointcloud2(T0, "lidar", arr, height=n_rows)
        msg.row_step, msg.data = row_step, data
        return w.serialize(msg, "sensor_msgs/msg/PointCloud2")
    finally:
        w.abort()


@pytest.mark.parametrize("fmt,encoding", [("ros1", "ros1"), ("mcap", "cdr")])
def test_only_valid_xyz_stamp_and_time_change_in_the_message_bytes(fmt, encoding, tmp_path):
    arr, dt = _padded_cloud()
    buf = _serialised(fmt, arr, dt, 3, 7, tmp_path)
    msg = parse_pointcloud2(buf, encoding == "cdr")
    conv = detect_time_convention(msg)
    cloud = decode_pointcloud2(msg, conv)
    assert len(cloud.points) == 21 - 4
    new_xyz = cloud.points * 2.0 + 1.0
    t_ref = cloud.end_ns
    data = deskewed_data(msg, conv, new_xyz, t_ref)
    out = patch_pointcloud2(buf, msg, data, t_ref, encoding)
    assert len(out) == len(buf)
    back = parse_pointcloud2(out, encoding == "cdr")
    assert back.header.stamp.sec * 10**9 + back.header.stamp.nanosec == t_ref
    again = decode_pointcloud2(back, conv)
    np.testing.assert_allclose(again.points, new_xyz, rtol=1e-6)  # float32 storage
    np.testing.assert_allclose(again.point_stamps_ns - T0, cloud.point_stamps_ns - T0, atol=FLOAT32_TIME_NS)
    view_in, view_out = points_view(np.array(msg.data), msg), points_view(np.array(back.data), back)
    for name in ("intensity", "ring"):
        np.testing.assert_array_equal(view_out[name], view_in[name])
    valid = valid_mask(view_in, conv)
    for c in "xyz":  # invalid points keep their bytes
        np.testing.assert_array_equal(view_out[c][~valid].view(np.uint32), view_in[c][~valid].view(np.uint32))
    assert np.isnan(view_out["time"].reshape(-1)[11])
    # every byte outside the stamp and the valid points' x/y/z/time is the same (row padding, the gap, seq)
    diff = np.flatnonzero(np.frombuffer(out, np.uint8) != np.frombuffer(buf, np.uint8))
    offset = msg.data.__array_interface__["data"][0] - np.frombuffer(buf, np.uint8).__array_interface__["data"][0]
    rel = diff[diff >= offset] - offset
    assert np.all(diff[diff < offset] < 12)  # the header stamp
    col = rel % msg.row_step  # position within its row
    assert np.all(col < 7 * 24)  # no row padding touched
    field_off = col % 24
    assert set(np.unique(field_off // 4).tolist()) <= {0, 1, 2, 5}  # x, y, z, time only


def test_time_fields_shift_by_their_unit_and_absolute_ones_stay():
    dt = np.dtype([("t", "<u4"), ("offset_time", "<i4"), ("time", "<f8"), ("timestamp", "<f8")])
    arr = np.zeros(4, dtype=dt)
    arr["t"] = [0, 10, 20, 30]
    arr["offset_time"] = [0, 10, 20, 30]
    arr["time"] = [0.0, 1e-8, 2e-8, 3e-8]
    arr["timestamp"] = 1.7e9
    view = arr.reshape(1, 4)
    shift_time_field(view, TimeConvention("c", "offset_time", 1.0), -25)
    shift_time_field(view, TimeConvention("c", "t", 1.0), -25)
    shift_time_field(view, TimeConvention("c", "time", 1e9), -25)
    shift_time_field(view, NAMED_CONVENTIONS["hesai"], -25)
    assert arr["offset_time"].tolist() == [-25, -15, -5, 5]
    assert arr["t"].tolist() == [0, 0, 0, 5]  # unsigned: held at zero (only invalid points go there)
    np.testing.assert_allclose(arr["time"], [-2.5e-8, -1.5e-8, -0.5e-8, 0.5e-8], atol=1e-20)
    assert arr["timestamp"].tolist() == [1.7e9] * 4


def test_a_count_mismatch_is_refused():
    arr, dt = _padded_cloud(3, 7)

    class Msg:  # the attributes the rewrite reads
        height, width, point_step, row_step, is_bigendian = 3, 7, 24, 7 * 24, False
        fields = [type("F", (), {"name": n, "offset": dt.fields[n][1], "datatype": d, "count": 1})
                  for n, d in zip(dt.names, (7, 7, 7, 7, 4, 7))]
        data = np.frombuffer(arr.tobytes(), np.uint8)
        header = type("H", (), {"stamp": type("S", (), {"sec": 1, "nanosec": 0})})

    with pytest.raises(Exception, match="valid points but 2 were de-skewed"):
        deskewed_data(Msg, NAMED_CONVENTIONS["velodyne"], np.zeros((2, 3)), 10**9)


def test_a_laserscan_becomes_one_point_per_beam_with_nan_where_no_return():
    class Scan:
        ranges = np.array([1.0, np.inf, 2.0, np.nan, 0.05], dtype=np.float32)
        intensities = np.array([5, 6, 7, 8, 9], dtype=np.float32)
        range_min, range_max, time_increment = 0.1, 30.0, 0.01
        header = type("H", (), {"stamp": type("S", (), {"sec": 10, "nanosec": 0})})

    xyz = np.array([[1.0, 0.5, 0.0], [0.0, 2.0, 0.1]])
    arr = laserscan_cloud(Scan, xyz, 10 * 10**9 + 40_000_000)
    assert arr.dtype.names == ("x", "y", "z", "intensity", "time")
    np.testing.assert_allclose(arr[[0, 2]]["x"], [1.0, 0.0])
    assert np.isnan(arr["x"][[1, 3, 4]]).all()
    np.testing.assert_allclose(arr["time"], [-0.04, -0.03, -0.02, -0.01, 0.0], atol=1e-7)
    np.testing.assert_array_equal(arr["intensity"], Scan.intensities)
