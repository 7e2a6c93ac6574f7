"""A car started at rest: its IMU's roll and pitch from gravity against the ground the LiDAR saw, its rotation
about the vertical from speeding up and braking (the wheels), against the simulated truth."""

from __future__ import annotations

import numpy as np
import pytest

from lio_cli.config.calibrate import CalibrateConfig
from lio_cli.geometry import inv_pose, so3_exp, so3_log
from lio_cli.jobs.calibrate import estimate as steps
from lio_cli.jobs.calibrate.passes import LidarTrajectory, SensorArrays
from lio_cli.jobs.calibrate.report import T_lidar_imu_of, rotation_cov_lidar
from lio_cli.jobs.calibrate.rest import rest_mounting
from lio_cli.model.records import ImuBatch
from lio_cli.simulation.calibration_inputs import START_NS, calibration_inputs
from lio_cli.simulation.scenarios import build_scenario
from lio_cli.simulation.sensors import ImuSpec


def ground_scan(rng, T_world_lidar: np.ndarray, n: int = 20000) -> np.ndarray:
    """The level ground (z = 0) around the vehicle and a wall, in the LiDAR frame, 1.5 cm of noise."""
    r, a = np.sqrt(rng.uniform(3.0**2, 30.0**2, n)), rng.uniform(-np.pi, np.pi, n)
    g = np.column_stack([r * np.cos(a), r * np.sin(a), np.zeros(n)]) + T_world_lidar[:3, 3] * [1, 1, 0]
    wall = np.column_stack([rng.uniform(-20, 20, n // 4), np.full(n // 4, 9.0), rng.uniform(0, 6, n // 4)])
    p = np.concatenate([g, wall]) + rng.normal(0, 0.015, (n + n // 4, 3))
    return (p - T_world_lidar[:3, 3]) @ T_world_lidar[:3, :3]


@pytest.fixture(scope="module")
def car():
    """20 s of a simulated car driving off from rest (straight, 9 deg of heading), its IMU yawed 30 deg,
    rolled and pitched 2 deg, 0.37 m from the base, its clock 20 ms late, its accelerometer's horizontal bias
    0.025 m/s^2 (0.15 deg of tilt); the estimates up to its wheels, and the ground its LiDAR saw at rest."""
    T = np.eye(4)
    T[:3, :3], T[:3, 3] = so3_exp(np.radians([2.0, -2.0, 30.0])), [0.3, -0.2, 0.1]
    sc = build_scenario("drive", start="still")
    spec = ImuSpec(accel_bias0_mps2=np.array([0.02, -0.015, 0.03]), gyro_bias0_radps=np.array([0.002, -0.003, 0.001]))
    ci = calibration_inputs(sc, 20.0, seed=5, T_base_imu=T, imu_time_offset_s=-0.02, imu_spec=spec)
    n = len(ci.lidar_stamps_ns)
    traj = LidarTrajectory(ci.lidar_stamps_ns, ci.T_world_lidar, n, n, "")
    imu = ImuBatch("imu", ci.imu.stamps_ns, ci.imu.gyro_radps, ci.imu.accel_mps2)
    T_wl0 = sc.trajectory.poses(np.array([0.0]))[0] @ ci.T_base_lidar  # the world level, the ground at z = 0
    rng = np.random.default_rng(0)
    scans = [(START_NS + k * 100_000_000, START_NS + (k + 1) * 100_000_000, ground_scan(rng, T_wl0))
             for k in range(15)]
    arrays = SensorArrays(imu=imu, wheel_stamps_ns=ci.wheel.stamps_ns, wheel_linear_mps=ci.wheel.linear_mps,
                          wheel_angular_radps=ci.wheel.angular_radps, first_scans=scans)
    est = steps.Estimates()
    steps.imu_at_rest(imu, None, None, est, "car.bag")
    steps.extrinsics(traj, imu, CalibrateConfig(), est, "car.bag", None, final=True, prior_offset=0.0)
    steps.wheels(arrays, traj, ci.T_base_lidar, CalibrateConfig(), est, "car.bag")
    return ci, arrays, imu, est


def errors_deg(est, ci) -> tuple[np.ndarray, np.ndarray]:
    """The mounting's error about the base x, y, z (deg) and its 1-sigma there."""
    Rbl = ci.T_base_lidar[:3, :3]
    err = so3_log(Rbl @ T_lidar_imu_of(est, None)[:3, :3] @ ci.T_base_imu[:3, :3].T)
    return np.degrees(err), np.degrees(np.sqrt(np.diag(Rbl @ rotation_cov_lidar(est) @ Rbl.T)))


def test_with_hand_eye_the_rest_replaces_only_what_it_measures_better(car):
    ci, arrays, imu, est = car
    est = est.trial()
    rest_mounting(arrays, imu, ci.T_base_lidar, None, est)
    err, sig = errors_deg(est, ci)
    assert np.abs(err).max() < 0.3 and (np.abs(err) <= 3 * sig).all() and (sig <= 0.3).all()
    assert not any(s.key.startswith("rotation") for s in est.skipped)
    assert any(n.startswith("the mounting's roll and pitch from gravity against the ground the LiDAR saw at rest")
               for n in est.notes)
    # the LiDAR trajectory simulated here is cleaner than a registration's: hand-eye is sharp about the vertical
    # (0.23 deg), the wheels' windows of 0.25 s sharper still (0.18 deg): they replace it there
    assert est.notes[-1].startswith("the mounting's rotation about the base z from the wheels' accelerations")
    assert sig[2] < 0.2


def test_without_hand_eye_the_rest_and_the_wheels_give_the_mounting_alone(car):
    ci, arrays, imu, est = car
    est = est.trial()
    est.rotation, est.lever = None, None
    rest_mounting(arrays, imu, ci.T_base_lidar, None, est)
    err, sig = errors_deg(est, ci)
    assert np.abs(err).max() < 0.3 and (np.abs(err) <= 3 * sig).all() and (sig[:2] <= 0.3).all()
    assert sig[2] <= 0.6  # the wheels' yaw also carries the tilt the gyro's noise integrates over the drive
    assert not any(s.key.startswith("rotation") for s in est.skipped)
    assert est.notes[-1].startswith("the mounting's rotation about the base z from the wheels' accelerations")


def test_without_wheels_the_rotation_about_the_vertical_is_named_not_estimated(car):
    ci, arrays, imu, est = car
    est = est.trial()
    est.rotation, est.lever = None, None
    bare = SensorArrays(imu=imu, first_scans=arrays.first_scans)
    rest_mounting(bare, imu, ci.T_base_lidar, None, est)
    err, sig = errors_deg(est, ci)
    up_est = (ci.T_base_lidar[:3, :3] @ T_lidar_imu_of(est, None)[:3, :3])[2]  # the base z in the IMU frame
    assert np.degrees(np.arccos(up_est @ ci.T_base_imu[2, :3])) < 0.3 and (sig[:2] <= 0.3).all() and sig[2] > 90
    reasons = {s.key: s.reason for s in est.skipped if s.key.startswith("rotation")}
    assert list(reasons) == ["rotation_z"]  # the LiDAR's z is the base's here
    assert reasons["rotation_z"] == ("hand-eye could not use the rotations; gravity and the ground at rest give the "
                                     "roll and pitch, not the rotation about the vertical: speed up and brake (with "
                                     "wheel odometry) to show it")


def test_scans_that_do_not_see_the_ground_leave_the_mounting_as_it_was(car):
    ci, arrays, imu, est = car
    est = est.trial()
    sky = [(a, b, p[p[:, 2] > 0]) for a, b, p in arrays.first_scans]
    rest_mounting(SensorArrays(imu=imu, first_scans=sky), imu, ci.T_base_lidar, None, est)
    assert est.rotation is car[3].rotation
    assert est.notes[-1].startswith("roll and pitch from gravity and the ground at rest: ground plane: ")
