"""PointCloud2 / LaserScan decoding: every per-point time convention, layouts, invalid returns."""

from __future__ import annotations

import numpy as np
import pytest
from rosbags.typesys import Stores, get_typestore

from lio_cli.errors import InputError
from lio_cli.io.messages.encode import MessageFactory
from lio_cli.io.messages.pointcloud import (
    decode_laserscan,
    decode_pointcloud2,
    detect_time_convention,
    parse_time_convention,
)

T0_NS = 1_700_000_000 * 10**9
STEP_NS = 1_953_125  # 1/512 s, exact in float32/float64
PERIOD_NS = 100_000_000
XYZ_TOL_M = 1e-6  # float32 storage of coordinates of a few metres
AZIMUTH_TOL_NS = 1_000  # stamps derived from atan2 of float32 coordinates
FLOAT64_EPOCH_TOL_NS = 250  # one float64 ulp of epoch seconds (2**-22 s = 238 ns)

F4, F8, U4 = "<f4", "<f8", "<u4"


@pytest.fixture(scope="module")
def make() -> MessageFactory:
    return MessageFactory(get_typestore(Stores.ROS2_HUMBLE))


def cloud_array(n: int, time_field: tuple[str, str] | None = None, *, offsets=None, itemsize=None,
                order: str = "<") -> np.ndarray:
    fields = [("x", order + "f4"), ("y", order + "f4"), ("z", order + "f4")]
    if time_field is not None:
        fields.append((time_field[0], order + time_field[1][1:]))
    spec = {"names": [f for f, _ in fields], "formats": [d for _, d in fields]}
    if offsets is not None:
        spec["offsets"] = offsets
    if itemsize is not None:
        spec["itemsize"] = itemsize
    arr = np.zeros(n, dtype=np.dtype(spec))
    az = 2 * np.pi * np.arange(n) / n
    arr["x"], arr["y"], arr["z"] = 5 * np.cos(az), 5 * np.sin(az), 0.5
    return arr


def assert_stamps_close(actual_ns, expected_ns, tol_ns: int) -> None:
    """Compare int64 stamps as integers (assert_allclose would go through float64, 256 ns ulp at epoch)."""
    diff = np.abs(np.asarray(actual_ns, np.int64) - np.asarray(expected_ns, np.int64))
    assert len(actual_ns) == len(expected_ns) and int(diff.max(initial=0)) <= tol_ns, diff


def xyz_of(arr: np.ndarray) -> np.ndarray:
    return np.stack([arr["x"], arr["y"], arr["z"]], axis=1).astype(np.float64)


# (field, dtype, values stored, expected offset ns from header, convention label, absolute)
K = np.arange(40, dtype=np.int64)
CONVENTIONS = {
    "velodyne time f4 s rel": ("time", F4, K / 512.0, K * STEP_NS, "velodyne", False),
    "ouster t u4 ns rel": ("t", U4, K * 2_500_001, K * 2_500_001, "ouster", False),
    "livox offset_time u4 ns rel": ("offset_time", U4, K * 1_000_003, K * 1_000_003, "livox", False),
    "hesai timestamp f8 s abs": ("timestamp", F8, T0_NS / 1e9 + 0.25 + K / 512.0, 250_000_000 + K * STEP_NS, "hesai", True),
    "timestamps f8 s abs": ("timestamps", F8, T0_NS / 1e9 + K / 512.0, K * STEP_NS, "stamps", True),
    "stamps f8 s rel": ("stamps", F8, K / 512.0, K * STEP_NS, "stamps", False),
    "header at end, time f4 negative": ("time", F4, (K - 39) / 512.0, (K - 39) * STEP_NS, "velodyne", False),
    "header at end, stamps f8 negative": ("stamps", F8, (K - 39) / 512.0, (K - 39) * STEP_NS, "stamps", False),
}


@pytest.mark.parametrize("case", CONVENTIONS, ids=list(CONVENTIONS))
def test_every_time_convention_gives_exact_stamps(make, case):
    field, dtype, values, offsets_ns, label, absolute = CONVENTIONS[case]
    arr = cloud_array(len(values), (field, dtype))
    arr[field] = values
    msg = make.pointcloud2(T0_NS, "lidar", arr)

    conv = detect_time_convention(msg)
    cloud = decode_pointcloud2(msg)

    assert (conv.name, conv.field, conv.absolute) == (label, field, absolute)
    assert cloud.point_stamps_ns.dtype == np.int64
    np.testing.assert_array_equal(cloud.point_stamps_ns, T0_NS + offsets_ns)
    np.testing.assert_allclose(cloud.points, xyz_of(arr), atol=XYZ_TOL_M)
    assert cloud.header_marks == ("end" if offsets_ns[-1] <= 0 else "start")
    assert cloud.stamp_ns == T0_NS and cloud.frame_id == "lidar" and cloud.dropped == 0


def test_absolute_float_stamps_at_a_fractional_header_keep_sub_microsecond_precision(make):
    header_ns = T0_NS + 123_456_789
    true_ns = header_ns + np.arange(20, dtype=np.int64) * 4_999_999
    arr = cloud_array(20, ("timestamp", F8))
    arr["timestamp"] = (true_ns // 10**9) + (true_ns % 10**9) * 1e-9  # what a driver stores
    cloud = decode_pointcloud2(make.pointcloud2(header_ns, "lidar", arr))
    assert_stamps_close(cloud.point_stamps_ns, true_ns, FLOAT64_EPOCH_TOL_NS)


def test_no_time_field_derives_stamps_from_azimuth_and_says_so(make):
    n = 64
    arr = cloud_array(n)  # points at azimuth 2*pi*k/n, counter-clockwise
    cloud = decode_pointcloud2(make.pointcloud2(T0_NS, "lidar", arr), scan_period_ns=PERIOD_NS)
    assert cloud.convention.name == "azimuth" and cloud.convention.field is None
    assert "azimuth" in cloud.convention.describe()
    expected = T0_NS + np.arange(n) * PERIOD_NS // n
    assert_stamps_close(cloud.point_stamps_ns, expected, AZIMUTH_TOL_NS)


def test_azimuth_stamps_follow_a_clockwise_spin(make):
    n = 64
    arr = cloud_array(n)
    arr["y"] = -arr["y"]  # azimuth decreasing, as a Velodyne spins
    cloud = decode_pointcloud2(make.pointcloud2(T0_NS, "lidar", arr), scan_period_ns=PERIOD_NS)
    expected = T0_NS + np.arange(n) * PERIOD_NS // n
    assert_stamps_close(cloud.point_stamps_ns, expected, AZIMUTH_TOL_NS)


def test_organised_cloud_without_time_uses_column_index(make):
    height, width = 4, 16
    arr = cloud_array(height * width)
    cloud = decode_pointcloud2(make.pointcloud2(T0_NS, "lidar", arr, height=height), scan_period_ns=PERIOD_NS)
    col = np.tile(np.arange(width), height)
    np.testing.assert_array_equal(cloud.point_stamps_ns, T0_NS + (col * (PERIOD_NS / width)).astype(np.int64))


def test_organised_cloud_drops_nan_and_zero_returns_with_their_stamps(make):
    height, width = 4, 8
    n = height * width
    arr = cloud_array(n, ("t", U4))
    arr["t"] = np.arange(n) * 1_000_000
    rng = np.random.default_rng(7)
    bad = rng.choice(n, size=10, replace=False)
    nan_idx, zero_idx = bad[:5], bad[5:]
    arr["x"][nan_idx] = np.nan
    arr["x"][zero_idx] = arr["y"][zero_idx] = arr["z"][zero_idx] = 0.0
    keep = np.setdiff1d(np.arange(n), bad)

    cloud = decode_pointcloud2(make.pointcloud2(T0_NS, "lidar", arr, height=height))

    assert cloud.dropped == 10 and len(cloud.points) == len(cloud.point_stamps_ns) == n - 10
    np.testing.assert_array_equal(cloud.point_stamps_ns, T0_NS + keep * 1_000_000)
    np.testing.assert_allclose(cloud.points, xyz_of(arr)[keep], atol=XYZ_TOL_M)


def test_points_with_nan_time_are_dropped_with_no_warning(make, recwarn):
    arr = cloud_array(10, ("time", F4))
    arr["time"] = np.arange(10) / 512.0
    arr["time"][3] = np.nan
    cloud = decode_pointcloud2(make.pointcloud2(T0_NS, "lidar", arr))
    assert cloud.dropped == 1
    np.testing.assert_array_equal(cloud.point_stamps_ns, T0_NS + np.delete(np.arange(10), 3) * STEP_NS)
    assert not [w for w in recwarn if issubclass(w.category, RuntimeWarning)]


def test_all_nan_cloud_decodes_to_zero_points_without_warnings(make, recwarn):
    arr = cloud_array(8, ("time", F4))
    arr["x"] = np.nan
    arr["time"] = np.nan
    msg = make.pointcloud2(T0_NS, "lidar", arr)
    cloud = decode_pointcloud2(msg)
    assert len(cloud.points) == 0 and len(cloud.point_stamps_ns) == 0 and cloud.dropped == 8
    assert detect_time_convention(msg).name == "velodyne"
    assert not [w for w in recwarn if issubclass(w.category, RuntimeWarning)]


def test_point_step_padding_is_skipped(make):
    # x y z at 0/4/8, 4 bytes of padding, time at 16, point_step 32 (PCL-style)
    arr = cloud_array(12, ("time", F4), offsets=[0, 4, 8, 16], itemsize=32)
    arr["time"] = np.arange(12) / 512.0
    msg = make.pointcloud2(T0_NS, "lidar", arr)
    assert msg.point_step == 32
    cloud = decode_pointcloud2(msg)
    np.testing.assert_array_equal(cloud.point_stamps_ns, T0_NS + np.arange(12) * STEP_NS)
    np.testing.assert_allclose(cloud.points, xyz_of(arr), atol=XYZ_TOL_M)


def test_row_padding_is_skipped(make):
    height, width, pad = 3, 5, 7
    arr = cloud_array(height * width, ("t", U4))
    arr["t"] = np.arange(height * width) * 1000
    msg = make.pointcloud2(T0_NS, "lidar", arr, height=height)
    rows = np.frombuffer(arr.tobytes(), np.uint8).reshape(height, -1)
    padded = np.concatenate([rows, np.full((height, pad), 0xAB, np.uint8)], axis=1).reshape(-1)
    msg.data = padded
    msg.row_step = rows.shape[1] + pad
    cloud = decode_pointcloud2(msg)
    np.testing.assert_array_equal(cloud.point_stamps_ns, T0_NS + np.arange(height * width) * 1000)
    np.testing.assert_allclose(cloud.points, xyz_of(arr), atol=XYZ_TOL_M)


def test_big_endian_cloud(make):
    arr = cloud_array(16, ("t", U4), order=">")
    arr["t"] = np.arange(16) * 123_457
    msg = make.pointcloud2(T0_NS, "lidar", arr, big_endian=True)
    cloud = decode_pointcloud2(msg)
    np.testing.assert_array_equal(cloud.point_stamps_ns, T0_NS + np.arange(16) * 123_457)
    np.testing.assert_allclose(cloud.points, xyz_of(arr), atol=XYZ_TOL_M)


def test_explicit_convention_overrides_detection(make):
    arr = cloud_array(10, ("time", F4))
    arr["time"] = np.arange(10)  # milliseconds, by this driver's own convention
    cloud = decode_pointcloud2(make.pointcloud2(T0_NS, "lidar", arr), parse_time_convention("time:ms"))
    np.testing.assert_array_equal(cloud.point_stamps_ns, T0_NS + np.arange(10) * 1_000_000)
    none = decode_pointcloud2(make.pointcloud2(T0_NS, "lidar", arr), parse_time_convention("none"))
    np.testing.assert_array_equal(none.point_stamps_ns, np.full(10, T0_NS))


def test_parse_time_convention_rejects_garbage_with_the_choices():
    with pytest.raises(InputError, match=r"unknown per-point time convention 'bogus' \(use velodyne"):
        parse_time_convention("bogus")
    assert parse_time_convention("stamp:us:abs").absolute and parse_time_convention("stamp:us:abs").scale_ns == 1e3


def test_missing_requested_time_field_is_input_error(make):
    msg = make.pointcloud2(T0_NS, "lidar", cloud_array(4))
    with pytest.raises(InputError, match="no per-point time field 't'"):
        decode_pointcloud2(msg, parse_time_convention("ouster"))


def test_cloud_without_xyz_is_input_error(make):
    arr = np.zeros(3, dtype=[("a", "<f4"), ("b", "<f4")])
    with pytest.raises(InputError, match=r"PointCloud2 has no x, y, z field\(s\)"):
        decode_pointcloud2(make.pointcloud2(T0_NS, "lidar", arr))


def test_short_data_and_bad_layout_are_input_errors(make):
    msg = make.pointcloud2(T0_NS, "lidar", cloud_array(10, ("t", U4)))
    msg.data = msg.data[:50]
    with pytest.raises(InputError, match="fewer than 1x10 points"):
        decode_pointcloud2(msg)
    msg = make.pointcloud2(T0_NS, "lidar", cloud_array(10, ("t", U4)))
    msg.point_step = 8  # fields reach byte 16
    with pytest.raises(InputError, match="do not fit its point_step of 8 bytes"):
        decode_pointcloud2(msg)


def test_empty_cloud_decodes_to_nothing(make):
    msg = make.pointcloud2(T0_NS, "lidar", cloud_array(0, ("t", U4)))
    cloud = decode_pointcloud2(msg)
    assert cloud.points.shape == (0, 3) and cloud.point_stamps_ns.shape == (0,)


def test_laserscan_planar_points_per_beam_stamps_invalid_dropped(make):
    n = 8
    ranges = np.array([1.0, np.inf, 2.0, np.nan, 0.01, 3.0, 50.0, 4.0])
    inc = np.pi / 8
    msg = make.laserscan(T0_NS, "laser", angle_min=-np.pi / 2, angle_increment=inc, time_increment_s=1 / 512,
                         scan_time_s=0.1, range_min=0.1, range_max=30.0, ranges=ranges)
    cloud = decode_laserscan(msg)
    keep = np.array([0, 2, 5, 7])
    ang = -np.pi / 2 + inc * keep
    assert cloud.planar and cloud.dropped == n - len(keep)
    np.testing.assert_array_equal(cloud.point_stamps_ns, T0_NS + keep * STEP_NS)
    expected = np.stack([ranges[keep] * np.cos(ang), ranges[keep] * np.sin(ang), np.zeros(len(keep))], axis=1)
    np.testing.assert_allclose(cloud.points, expected, atol=XYZ_TOL_M)


def test_azimuth_stamps_start_at_the_first_valid_point(make):
    n = 64
    arr = cloud_array(n)
    arr["x"][0] = np.nan  # a no-return first: stamps must not inherit its NaN azimuth
    cloud = decode_pointcloud2(make.pointcloud2(T0_NS, "lidar", arr), scan_period_ns=PERIOD_NS)
    assert cloud.dropped == 1
    expected = T0_NS + np.arange(n - 1) * PERIOD_NS // n
    assert_stamps_close(cloud.point_stamps_ns, expected, AZIMUTH_TOL_NS)


def _split_cloud(n: int, sec_ns: np.ndarray) -> np.ndarray:
    arr = cloud_array(n)
    out = np.zeros(n, dtype=[("x", F4), ("y", F4), ("z", F4), ("time_sec", U4), ("time_nsec", U4)])
    for c in "xyz":
        out[c] = arr[c]
    out["time_sec"], out["time_nsec"] = sec_ns // 10**9, sec_ns % 10**9
    return out


def test_time_split_over_seconds_and_nanoseconds_fields_is_detected_and_exact(make):
    """Luminar's time_sec + time_nsec (absolute, header at the last point): exact int64 stamps, the header at
    the scan's end, and a description naming both fields; ``--point-time time_sec+time_nsec`` says the same."""
    header_ns = T0_NS + 987_654_321
    true_ns = header_ns - (39 - K) * 2_222_223  # crossing a whole second on the way
    msg = make.pointcloud2(header_ns, "luminar", _split_cloud(40, true_ns))
    conv = detect_time_convention(msg)
    assert (conv.name, conv.field, conv.field_ns, conv.absolute) == ("split", "time_sec", "time_nsec", True)
    assert "'time_sec' (s) + 'time_nsec' (ns)" in conv.describe()
    cloud = decode_pointcloud2(msg)
    np.testing.assert_array_equal(cloud.point_stamps_ns, true_ns)
    assert cloud.header_marks == "end"
    assert parse_time_convention("time_sec+time_nsec") == conv
    rel = parse_time_convention("time_sec+time_nsec:rel")
    assert not rel.absolute and rel.field_ns == "time_nsec"


def test_unorganised_cloud_not_in_firing_order_gets_no_azimuth_stamps(make):
    """No time field and points in no spinning order (a raster scanner, a sorted cloud): every point is at the
    header stamp and the convention says 'none', not 'azimuth'."""
    arr = cloud_array(64)
    arr = arr[np.random.default_rng(3).permutation(64)]
    cloud = decode_pointcloud2(make.pointcloud2(T0_NS, "lidar", arr))
    assert cloud.convention.name == "none" and "azimuth" not in cloud.convention.describe()
    np.testing.assert_array_equal(cloud.point_stamps_ns, np.full(64, T0_NS))


@pytest.mark.parametrize("value", [5e5, 1e300, -7200.0], ids=["5e5 s", "1e300 s", "-2 h"])
def test_a_point_with_an_absurd_time_is_dropped_and_counted_without_warnings(make, recwarn, value):
    arr = cloud_array(40, ("time", F8))
    arr["time"] = K / 512.0
    arr["time"][7] = value
    cloud = decode_pointcloud2(make.pointcloud2(T0_NS, "lidar", arr))
    assert (cloud.dropped, cloud.bad_times, len(cloud.points)) == (1, 1, 39)
    np.testing.assert_array_equal(cloud.point_stamps_ns, T0_NS + np.delete(K, 7) * STEP_NS)
    np.testing.assert_allclose(cloud.points, np.delete(xyz_of(arr), 7, axis=0), atol=XYZ_TOL_M)
    assert cloud.kept is not None and not cloud.kept[7] and cloud.kept.sum() == 39
    assert not [w for w in recwarn if issubclass(w.category, RuntimeWarning)]


def test_one_absurd_time_among_the_first_values_does_not_make_the_field_absolute(make):
    arr = cloud_array(40, ("time", F8))
    arr["time"] = K / 512.0
    arr["time"][0] = 5e7  # beyond the 'epoch-sized' threshold: only the typical value decides
    conv = detect_time_convention(make.pointcloud2(T0_NS, "lidar", arr))
    assert not conv.absolute
