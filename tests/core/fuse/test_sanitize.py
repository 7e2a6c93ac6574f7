"""Cleaning of each source: order, duplicates, NaN, bogus IMU rows, ROS covariance conventions, counted."""

from __future__ import annotations

import numpy as np

from lio_cli.core.fuse.inputs import GpsSeries, ImuSeries, NoiseOptions, PoseSeries, WheelSeries
from lio_cli.core.fuse.report import SourceReport
from lio_cli.core.fuse.sanitize import clean_gps, clean_imu, clean_odom, clean_wheel, gap_threshold_ns, order_and_dedupe

NOISE = NoiseOptions()


def test_order_and_dedupe_counts_reordered_and_duplicates():
    rep = SourceReport()
    stamps = np.array([10, 30, 20, 30, 40, 5], dtype=np.int64)
    keep = order_and_dedupe(stamps, np.ones(6, bool), rep)
    # arrival order 10, 30, 20 (late), 30 (duplicate of the second), 40, 5 (late)
    np.testing.assert_array_equal(stamps[keep], [5, 10, 20, 30, 40])
    assert keep[3] == 1  # the first of the duplicated stamps is kept
    assert rep.notes == {"reordered": 2}
    assert rep.rejected == {"duplicate_stamp": 1}


def test_imu_rows_nan_and_all_zero_are_rejected_and_orientation_conventions_handled():
    n = 6
    stamps = np.arange(n, dtype=np.int64) * 10_000_000
    gyro = np.tile([0.01, 0.02, 0.03], (n, 1))
    acc = np.tile([0.0, 0.0, 9.81], (n, 1))
    gyro[1, 0] = np.nan
    gyro[2], acc[2] = 0.0, 0.0  # placeholder message: every value exactly zero
    q = np.tile([0.0, 0.0, 0.0, 2.0], (n, 1))  # not normalised: cleaned to unit length
    q[3] = 0.0  # "no orientation" written as a zero quaternion
    cov = np.tile(np.eye(3) * 1e-4, (n, 1, 1))
    cov[4, 0, 0] = -1.0  # ROS: orientation_covariance[0] = -1 means no orientation
    cov[5] = 0.0  # unknown covariance: the default is used
    rep = SourceReport()
    out = clean_imu(ImuSeries(stamps, gyro, acc, np.eye(4), q, None, cov), NOISE, rep)
    np.testing.assert_array_equal(out.stamps_ns, stamps[[0, 3, 4, 5]])
    assert rep.rejected == {"nan": 1, "all_zero": 1}
    np.testing.assert_array_equal(out.orientation_valid, [True, False, False, True])
    np.testing.assert_allclose(out.orientation_xyzw[0], [0, 0, 0, 1.0])
    np.testing.assert_allclose(out.orientation_cov[3], np.eye(3) * NOISE.orientation_sigma_rad**2)
    np.testing.assert_allclose(out.orientation_cov[0], np.eye(3) * 1e-4)
    assert rep.notes == {"orientation_absent": 2, "default_noise": 1}


def test_wheel_twist_only_rows_and_covariance_defaults():
    stamps = np.array([0, 20, 40, 60], dtype=np.int64) * 1_000_000
    vel = np.array([[1.0, np.nan, np.nan], [np.nan, np.nan, np.nan], [1.1, 0.0, np.inf], [0.9, np.nan, np.nan]])
    yaw = np.array([0.1, np.nan, np.nan, 0.2])
    vvar = np.array([[0.01, 0, 0], [0, 0, 0], [-1.0, 0, 0], [np.nan, 0, 0]])
    rep = SourceReport()
    out = clean_wheel(WheelSeries(stamps, vel, yaw, vvar, np.array([0.0, 0.0, 0.0, 4e-4])), {"speed", "yaw_rate"}, NOISE, rep)
    np.testing.assert_array_equal(out.stamps_ns, stamps[[0, 2, 3]])  # row 1 carries nothing usable
    assert rep.rejected == {"nan": 1}
    assert np.isnan(out.velocity_mps[1, 2])  # inf becomes "absent"
    s0, rel = NOISE.wheel_speed_sigma_mps, NOISE.wheel_speed_rel_sigma
    np.testing.assert_allclose(out.velocity_var[:, 0], [0.01, s0**2 + (rel * np.hypot(1.1, 0.0))**2, s0**2 + (rel * 0.9)**2])
    np.testing.assert_allclose(out.yaw_rate_var[[0, 2]], [NOISE.wheel_yaw_rate_sigma_radps**2, 4e-4])
    # defaulted: speed variance of rows 2 and 3, yaw-rate variance of row 0
    assert rep.notes["default_noise"] == 3


def test_odom_zero_quaternion_pose_is_rejected():
    T = np.tile(np.eye(4), (3, 1, 1))
    T[1, :3, :3] = 0.0  # what a quaternion (0,0,0,0) turns into
    T[2, 0, 3] = np.nan
    rep = SourceReport()
    out = clean_odom(PoseSeries(np.array([0, 1, 2], np.int64), T), NOISE, rep)
    assert len(out) == 1
    assert rep.rejected == {"invalid_pose": 1, "nan": 1}
    np.testing.assert_allclose(out.position_sigma_m, [NOISE.odom_position_sigma_m])


def test_gps_without_fix_is_rejected_and_bad_covariance_defaulted():
    p = np.zeros((3, 3))
    cov = np.stack([np.eye(3) * 0.25, np.zeros((3, 3)), np.eye(3)])
    rep = SourceReport()
    out = clean_gps(GpsSeries(np.array([0, 1, 2], np.int64), p, cov, np.array([True, True, False])), NOISE, rep)
    assert len(out) == 2
    assert rep.rejected == {"no_fix": 1}
    np.testing.assert_allclose(out.cov_m2[1], np.diag([NOISE.gps_position_sigma_m**2] * 2 + [NOISE.gps_vertical_sigma_m**2]))
    assert rep.notes == {"default_noise": 1}


def test_gap_threshold_is_periods_of_the_median_spacing():
    stamps = np.arange(100, dtype=np.int64) * 5_000_000  # 200 Hz
    assert gap_threshold_ns(stamps, 5.0, 1_000_000) == 25_000_000
    assert gap_threshold_ns(stamps, 5.0, 50_000_000) == 50_000_000


def test_the_default_wheel_speed_sigma_grows_with_the_speed():
    """A wheel radius 1 % off is 0.01 m/s at 1 m/s but 0.1 m/s at 10 m/s: a fixed 0.05 m/s let a car's wheels
    outweigh LiDAR odometry (fused ATE 0.25 m on `lio simulate drive`, 0.03 m without the wheels; now 0.09 m)."""
    stamps = np.array([0, 20, 40], dtype=np.int64) * 1_000_000
    vel = np.array([[0.0, 0.0, 0.0], [1.0, 0.2, 0.0], [-10.0, 0.0, 0.0]])
    out = clean_wheel(WheelSeries(stamps, vel, np.full(3, np.nan)), {"velocity"}, NOISE, SourceReport())
    s0 = NOISE.wheel_speed_sigma_mps
    r1 = np.hypot(s0, 0.02 * np.hypot(1.0, 0.2))  # each component: a share of the speed (scale or angle errors)
    np.testing.assert_allclose(np.sqrt(out.velocity_var), [[s0] * 3, [r1] * 3, [np.hypot(s0, 0.2)] * 3])


def test_imu_and_wheel_values_beyond_any_sensor_are_rejected_as_out_of_range():
    n = 5
    stamps = np.arange(n, dtype=np.int64) * 10_000_000
    gyro = np.tile([0.01, 0.02, 0.03], (n, 1))
    acc = np.tile([0.0, 0.0, 9.81], (n, 1))
    acc[1, 0] = 1e300  # what `lio info --check` calls bad: dropped, not squared into an overflow
    gyro[3, 2] = -2e3
    rep = SourceReport()
    with np.errstate(all="raise"):  # no RuntimeWarning on the way
        out = clean_imu(ImuSeries(stamps, gyro, acc, np.eye(4)), NOISE, rep)
    np.testing.assert_array_equal(out.stamps_ns, stamps[[0, 2, 4]])
    assert rep.rejected == {"out_of_range": 2}
    vel = np.array([[1.0, 0, 0], [1e300, 0, 0], [1.0, 0, 0]])
    rep = SourceReport()
    with np.errstate(all="raise"):
        out = clean_wheel(WheelSeries(stamps[:3], vel, np.array([0.1, 0.1, 5e3])), {"speed"}, NOISE, rep)
    np.testing.assert_array_equal(out.stamps_ns, stamps[[0, 2]])  # the yaw rate is not used: row 2 stays
    assert rep.rejected == {"out_of_range": 1}
