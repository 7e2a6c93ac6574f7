"""Columns -> core series: what each message carries, decided as ROS documents it."""

from __future__ import annotations

import numpy as np

from lio_cli.geodesy import EnuFrame
from lio_cli.geometry import rot_to_quat_xyzw, so3_exp
from lio_cli.io.messages.decode import ODOMETRY
from lio_cli.io.sensors.series import ImuColumns, MotionColumns
from lio_cli.jobs.fuse.convert import (
    carries_lateral_speed, gps_series, imu_series, pose_series, twist_frame, wheel_series,
)
from lio_cli.model.gps import GpsTrack

T0 = 1_700_000_000 * 10**9


def _odometry(n=50, lin=(1.0, 0.0, 0.0), w=0.5, parent=False, twist_cov=None, pose_cov=None):
    st = T0 + np.arange(n, dtype=np.int64) * 50_000_000
    t = (st - T0) * 1e-9
    yaw = w * t
    p = np.column_stack([np.sin(yaw) / w, (1 - np.cos(yaw)) / w, np.zeros(n)])
    q = rot_to_quat_xyzw(so3_exp(np.column_stack([np.zeros((n, 2)), yaw])))
    v = np.tile(lin, (n, 1)).astype(float)
    if parent:
        v = np.einsum("nij,nj->ni", so3_exp(np.column_stack([np.zeros((n, 2)), yaw])), v)
    return MotionColumns("/odom", ODOMETRY, "odom", "base_link", st, p, q,
                         np.zeros((n, 36)) if pose_cov is None else pose_cov, v,
                         np.tile([0.0, 0.0, w], (n, 1)), np.zeros((n, 36)) if twist_cov is None else twist_cov)


def test_twist_frame_from_the_poses():
    assert twist_frame(_odometry())[0] == "child"
    frame, why = twist_frame(_odometry(parent=True))
    assert frame == "parent" and "rotated into the base" in why
    c = _odometry(parent=True)
    c.quat_xyzw[:] = 0.0  # a twist-only driver: the poses cannot tell
    assert twist_frame(c) == ("child", "REP 105 (the poses cannot tell: no valid orientation or too little motion)")
    body = wheel_series(_odometry(parent=True), "parent").velocity_mps
    np.testing.assert_allclose(body, np.tile([1.0, 0.0, 0.0], (50, 1)), atol=1e-12)


def test_a_twist_of_1e300_does_not_sway_the_frame_test_nor_overflow():
    # fuzz, issue 32: one wheel twist of 1e300 overflowed the misfit's norm (a numpy RuntimeWarning on stderr)
    import warnings

    c = _odometry(parent=True)
    c.linear_mps[10, 0] = 1e300
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        frame, why = twist_frame(c)
    assert frame == "parent" and "rotated into the base" in why


def test_unmeasured_and_unfilled_components_are_nan():
    cov = np.zeros((50, 36))
    cov[:, 7] = 1e6  # lateral speed not measured (robot_localization's convention)
    cov[:, 0] = 0.04
    w = wheel_series(_odometry(twist_cov=cov), "child")
    assert np.isnan(w.velocity_mps[:, 1]).all() and np.isfinite(w.velocity_mps[:, [0, 2]]).all()
    np.testing.assert_allclose(w.velocity_var[:, 0], 0.04)
    assert np.isfinite(w.yaw_rate_radps).all()
    assert np.isnan(wheel_series(_odometry(w=1e-9), "child").yaw_rate_radps).sum() == 0
    unfilled = _odometry()
    unfilled.angular_radps[:] = 0.0  # a yaw rate that is 0 in every message was never filled
    assert np.isnan(wheel_series(unfilled, "child").yaw_rate_radps).all()


def test_lateral_speed_marks_a_holonomic_base():
    assert not carries_lateral_speed(wheel_series(_odometry(), "child"))
    assert carries_lateral_speed(wheel_series(_odometry(lin=(0.5, 0.4, 0.0)), "child"))


def test_imu_orientation_validity_offset_and_biases():
    n = 4
    q = np.array([[0, 0, 0, 1.0], [0, 0, 0, 0.0], [0, 0, 0.6, 0.8], [0, 0, 0, 1.0]])
    cov = np.zeros((n, 9))
    cov[3, 0] = -1.0  # "no orientation"
    cols = ImuColumns("/imu", "imu", T0 + np.arange(n), np.ones((n, 3)), np.full((n, 3), 2.0), q, cov)
    s = imu_series(cols, np.eye(4), offset_ns=-5, gyro_bias=[0.5, 0.5, 0.5], accel_bias=[1.0, 0.0, 0.0])
    np.testing.assert_array_equal(s.orientation_valid, [True, False, True, False])
    np.testing.assert_array_equal(s.stamps_ns, T0 + np.arange(n) - 5)
    np.testing.assert_allclose(s.gyro_radps, 0.5)
    np.testing.assert_allclose(s.accel_mps2[0], [1.0, 2.0, 2.0])
    assert s.orientation_cov.shape == (n, 3, 3)


def test_pose_sigmas_from_odometry_covariance():
    cov = np.zeros((50, 36))
    cov[:, [0, 7]] = 0.01
    cov[:, 14] = 1e6  # z not measured: left out of the mean
    cov[:, 35] = 0.0004
    p = pose_series(_odometry(pose_cov=cov))
    np.testing.assert_allclose(p.position_sigma_m, 0.1)
    np.testing.assert_allclose(p.rotation_sigma_rad, 0.02)
    c = _odometry()
    c.quat_xyzw[3] = 0.0
    T = pose_series(c).poses
    assert np.all(T[3, :3, :3] == 0.0) and np.isnan(pose_series(c).position_sigma_m).all()  # left for the core


def test_gps_unknown_covariance_becomes_the_default():
    o = EnuFrame(47.0, 8.0, 400.0)
    track = GpsTrack("/fix", T0 + np.arange(2), np.zeros((2, 3)), np.stack([np.eye(3)] * 2), np.array([0, 2]),
                     np.zeros(2, int), o, "given", 2, 0, 0, 0)
    g = gps_series(track)
    assert np.isnan(g.cov_m2[0]).all()
    np.testing.assert_array_equal(g.cov_m2[1], np.eye(3))
