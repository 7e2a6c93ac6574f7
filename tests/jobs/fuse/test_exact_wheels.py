"""IMU + exact wheels, the default estimator (planar, smoothed): the fused height follows the ground's heave
(the accelerometer's), which the wheels' flat dead reckoning cannot, and the fused horizontal path is as good as
the exact wheels' own, not the gyro's noise integrated between their messages."""

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


def _fused_and_wheels(log, gt) -> tuple[float, float, float, float]:
    """(horizontal, vertical) errors of the default fuse, then of the wheels' dead reckoning."""
    run = run_fuse(FuseJob(log, FuseConfig(rate_hz=50.0)))
    assert run.metrics["estimator"] == "planar"
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
