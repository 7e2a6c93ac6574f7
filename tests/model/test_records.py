"""lio_cli/model/records.py: the IMU re-stamp onto the LiDAR's clock."""

import numpy as np

from lio_cli.model.records import ImuBatch, on_lidar_clock


def test_an_imu_clock_offset_is_added_to_the_stamps():
    stamps = np.array([1_000, 2_000, 3_000], np.int64)
    np.testing.assert_array_equal(on_lidar_clock(stamps, -250), [750, 1_750, 2_750])
    assert on_lidar_clock(stamps, 0).dtype == np.int64


def test_a_shifted_batch_keeps_its_samples_and_frame():
    gyro, accel = np.arange(6.0).reshape(2, 3), np.ones((2, 3))
    batch = ImuBatch("imu", np.array([10, 20], np.int64), gyro, accel)
    moved = batch.shifted(5)
    np.testing.assert_array_equal(moved.stamps_ns, [15, 25])
    assert moved.frame_id == "imu" and moved.gyro_radps is gyro and moved.accel_mps2 is accel
    np.testing.assert_array_equal(batch.stamps_ns, [10, 20])  # the original is untouched


def test_a_scans_span_is_its_points_first_and_last_stamp_or_else_its_header():
    from lio_cli.model.records import PointCloud, TimeConvention

    conv = TimeConvention("none", None, 1.0)
    cloud = PointCloud(5_000, "lidar", np.zeros((3, 3)), np.array([7_000, 6_000, 9_000], np.int64), conv)
    assert (cloud.start_ns, cloud.end_ns) == (6_000, 9_000)
    assert (cloud.start_ns, cloud.end_ns) == (6_000, 9_000)  # asked again: the same
    empty = PointCloud(5_000, "lidar", np.zeros((0, 3)), np.zeros(0, np.int64), conv)
    assert (empty.start_ns, empty.end_ns) == (5_000, 5_000)
