"""IMU + exact wheels, the default estimator (planar, smoothed): the fused height follows the ground's heave
(the accelerometer's) and its roll and pitch the body's tilt (gyro and accelerometer), which the wheels' flat dead
reckoning cannot, and the fused horizontal path is as good as the exact wheels' own, not the gyro's noise
integrated between their messages."""

from __future__ import annotations

import numpy as np
import pytest

from lio_cli.config.fuse import FuseConfig
from lio_cli.evaluation import EvalOptions, evaluate
from lio_cli.io.files.trajectory import read_tum
from lio_cli.io.logs.reader import open_log
from lio_cli.jobs.fuse.job import FuseJob, run_fuse
from lio_cli.model.trajectory import Trajectory
from lio_cli.simulation.run import simulate

NS = 1_000_000_000


def _log(tmp_path_factory, scenario: str):
    log = tmp_path_factory.mktemp(scenario) / f"{scenario}.mcap"
    simulate(scenario, log, duration_s=20.0, seed=5, wheel_errors=False, lidar=False)
    gt = Trajectory(*read_tum(log.with_name(f"{scenario}.gt.tum")), name="gt")
    return log, gt


@pytest.fixture(scope="module")
def rover(tmp_path_factory):
    return _log(tmp_path_factory, "rover")


@pytest.fixture(scope="module")
def car(tmp_path_factory):
    return _log(tmp_path_factory, "drive")


def _errors(gt: Trajectory, stamps: np.ndarray, poses: np.ndarray) -> tuple[float, float]:
    """(horizontal, vertical) RMS error after one SE(3) fit."""
    res = evaluate(gt, Trajectory(stamps, poses, name="est"), EvalOptions(max_diff_ns=1_000_000))
    d = res.association.ref.poses[:, :3, 3] - res.est_aligned[:, :3, 3]
    return float(np.sqrt(np.mean(np.sum(d[:, :2] ** 2, axis=1)))), float(np.sqrt(np.mean(d[:, 2] ** 2)))


def _wheel_dead_reckoning(log) -> tuple[np.ndarray, np.ndarray]:
    stamps, poses = [], []
    with open_log(log) as lg:
        for _, _, _, m in lg.messages(["/wheel/odom"]):
            p, q = m.pose.pose.position, m.pose.pose.orientation
            yaw = 2.0 * np.arctan2(q.z, q.w)
            T = np.eye(4)
            T[:2, :2] = [[np.cos(yaw), -np.sin(yaw)], [np.sin(yaw), np.cos(yaw)]]
            T[:3, 3] = (p.x, p.y, p.z)
            stamps.append(m.header.stamp.sec * NS + m.header.stamp.nanosec)
            poses.append(T)
    return np.array(stamps, np.int64), np.array(poses)


def _roll_pitch(gt: Trajectory, stamps: np.ndarray, poses: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(n,2) roll and pitch (deg) of the truth and of the estimate at the truth's matched stamps. Up in the body
    (a rotation's third row) is yaw-free: no alignment."""
    res = evaluate(gt, Trajectory(stamps, poses, name="est"), EvalOptions(max_diff_ns=1_000_000))

    def angles(R: np.ndarray) -> np.ndarray:
        up = R[:, 2, :3]
        return np.degrees(np.column_stack([np.arctan2(up[:, 1], up[:, 2]), -np.arcsin(up[:, 0])]))

    return angles(res.association.ref.poses), angles(res.association.est.poses)


def _fused(log):
    run = run_fuse(FuseJob(log, FuseConfig(rate_hz=50.0)))
    assert run.metrics["estimator"] == "planar"
    return run


def _fused_and_wheels(log, gt) -> tuple[float, float, float, float]:
    """(horizontal, vertical) errors of the default fuse, then of the wheels' dead reckoning."""
    run = _fused(log)
    core = run.metrics["core"]  # the planar filter leaves the accelerometer out, the height comes from it: named
    assert "heave" in core and core["use"]["imu"] == ["accel", "gyro"]
    return (*_errors(gt, run.trajectory.stamps_ns, run.trajectory.poses), *_errors(gt, *_wheel_dead_reckoning(log)))


def test_rover_height_follows_the_heave(rover):
    h, z, h_w, z_w = _fused_and_wheels(*rover)
    assert z_w > 0.025  # the ground heaves by centimetres: the flat wheels miss all of it
    assert z < 0.4 * z_w  # a flat output (the planar filter's) has z == z_w
    assert h < 1.2 * h_w + 0.005


def test_car_with_exact_wheels_is_as_good_as_their_dead_reckoning(car):
    h, z, h_w, z_w = _fused_and_wheels(*car)
    # before: the turn rate followed the gyro's noise between wheel messages and the position lagged the speed
    # by half a step: 2.5x the wheels' horizontal error on such a drive
    assert h < 1.5 * h_w
    assert z < 0.85 * z_w  # the suspension's heave (1.3 Hz) from the accelerometer


@pytest.mark.parametrize("name", ["rover", "car"])
def test_roll_and_pitch_follow_the_body(name, request):
    log, gt = request.getfixturevalue(name)
    run = _fused(log)
    truth, est = _roll_pitch(gt, run.trajectory.stamps_ns, run.trajectory.poses)
    err = est - truth
    # the ground tilts the rover by degrees, the suspension the car by tenths of one; a level pose (the planar
    # filter's own) misses all of it
    assert (truth.std(axis=0) > 0.4).all()
    # the roll followed (measured: rover 0.016 deg, car 0.078 of 1.38 and 0.58; the gyro alone, without the
    # accelerometer's fit, 0.65 and 0.70); the pitch above the heave's crossover, where the flat path is level too
    # (rover 0.17 of 1.22, car 0.13 of 0.48: the gyro's there) ...
    assert err[:, 0].std() < 0.2 * truth[:, 0].std() and err[:, 1].std() < 0.35 * truth[:, 1].std(), err.std(axis=0)
    # ... about the log's median: the truth's own mean tilt over 20 s (0.05-0.16 deg here) and the accelerometer's
    # bias are one to the data
    assert (np.abs(err.mean(axis=0)) < 0.25).all(), err.mean(axis=0)
    assert run.metrics["core"]["level"]["crossover_hz"] > 0
