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
