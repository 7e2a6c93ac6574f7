"""The planar output's height over hills: its path climbs the grade the IMU's slow pitch shows (``grade.estimate``,
``heave.climb``) where that climb stands out of what the body's sway alone would climb; on flat ground, and under
an IMU yawed against its calibration, it stays about a level."""

from __future__ import annotations

from dataclasses import replace
from types import SimpleNamespace

import numpy as np
import pytest

import lio_cli.core.fuse.grade as grade
from lio_cli.core.fuse import FuseOptions, fuse
from lio_cli.core.fuse.heave import climb
from lio_cli.evaluation import EvalOptions, Trajectory, evaluate
from lio_cli.simulation.fusion_case import simulate_case


def _ate(case, res) -> float:
    ref = Trajectory(case.truth_stamps_ns, case.truth_poses, "gt")
    est = Trajectory(res.stamps_ns, res.poses, "est")
    return evaluate(ref, est, EvalOptions(align="se3")).stats["ape"]["trans"]["rmse"]


def test_the_climb_is_the_forward_distance_times_the_grade():
    stamps = np.arange(0, 10_000_000_001, 10_000_000, dtype=np.int64)  # 10 s at 100 Hz
    yaw, speed = np.radians(30.0), 2.0
    poses = np.tile(np.eye(4), (len(stamps), 1, 1))
    poses[:, :2, :2] = [[np.cos(yaw), -np.sin(yaw)], [np.sin(yaw), np.cos(yaw)]]
    s = speed * stamps * 1e-9
    poses[:, 0, 3], poses[:, 1, 3] = s * np.cos(yaw), s * np.sin(yaw)
    prep = SimpleNamespace(imu=SimpleNamespace(stamps_ns=stamps[::2]))
    pitch = np.where(stamps[::2] < 5e9, np.radians(-2.0), np.radians(1.0))  # nose up (Z-Y-X) climbs
    z = climb(prep, SimpleNamespace(stamps_ns=stamps, poses=poses), pitch)
    assert z[500] == pytest.approx(10.0 * np.sin(np.radians(2.0)), abs=2e-3)
    assert z[-1] == pytest.approx(10.0 * (np.sin(np.radians(2.0)) - np.sin(np.radians(1.0))), abs=2e-3)
    backwards = poses.copy()
    backwards[:, :2, 3] *= -1.0  # reversing down the same line: the same grade now descends
    assert climb(prep, SimpleNamespace(stamps_ns=stamps, poses=backwards), pitch)[500] == pytest.approx(-z[500])


def test_a_car_over_gentle_hills_climbs_them(hills_car, monkeypatch):
    # 0.3 m high, 100 m apart (1.1 deg at the steepest): the planar filter's level height missed them by 0.19 m
    case = hills_car
    res = fuse(case.inputs, FuseOptions(rate_hz=20.0, estimator="planar", smooth=True))
    g = res.info["level"]["grade"]
    assert g["followed"] and g["climb_rms_m"] > 3.0 * g["sway_climb_rms_m"], g
    assert res.info["heave"]["model"] == "accelerometer about the grade's climb"
    monkeypatch.setattr(grade, "SIGNIFICANCE", np.inf)
    flat = fuse(case.inputs, FuseOptions(rate_hz=20.0, estimator="planar", smooth=True))
    assert not flat.info["level"]["grade"]["followed"]
    assert _ate(case, res) < 0.3 * _ate(case, flat), (_ate(case, res), _ate(case, flat))  # 0.044 against 0.180 m


def test_a_flat_drive_keeps_its_level():
    case = simulate_case("drive", 45.0, seed=1, wheel_errors=False)
    res = fuse(case.inputs, FuseOptions(rate_hz=20.0, estimator="planar", smooth=True))
    g = res.info["level"]["grade"]
    # the sway's slow leak climbs less than the sway itself (0.029 against 0.044 m): no grade
    assert not g["followed"] and g["climb_rms_m"] < 1.5 * g["sway_climb_rms_m"], g
    assert res.info["heave"]["model"] == "accelerometer about a level"
    assert _ate(case, res) < 0.012  # 0.0063 m


def _pitch_error_deg(case, res) -> float:
    """RMS of the output's pitch against the truth's, each about its mean (the mean is the mount's to the data)."""
    truth = np.interp(res.stamps_ns, case.truth_stamps_ns, -np.arcsin(case.truth_poses[:, 2, 0]))
    d = -np.arcsin(np.clip(res.poses[:, 2, 0], -1.0, 1.0)) - truth
    return float(np.degrees(np.std(d)))


@pytest.fixture(scope="module")
def hills_car():
    return simulate_case("drive", 45.0, seed=1, wheel_errors=False, hills=(0.3, 100.0))


def test_the_pose_pitches_with_the_grade(hills_car, monkeypatch):
    res = fuse(hills_car.inputs, FuseOptions(rate_hz=20.0, estimator="planar", smooth=True))
    monkeypatch.setattr(grade, "SIGNIFICANCE", np.inf)
    flat = fuse(hills_car.inputs, FuseOptions(rate_hz=20.0, estimator="planar", smooth=True))
    # measured 0.025 against 0.73 deg held level
    assert _pitch_error_deg(hills_car, res) < 0.1 < 0.5 < _pitch_error_deg(hills_car, flat)


def test_an_imu_gap_does_not_hide_the_grade(hills_car):
    imu = hills_car.inputs.imu
    t = (imu.stamps_ns - imu.stamps_ns[0]) * 1e-9
    keep = (t < 20.0) | (t > 22.0)  # 2 s without the IMU: its travel once counted as two samples' sway
    cut = replace(imu, stamps_ns=imu.stamps_ns[keep], gyro_radps=imu.gyro_radps[keep], accel_mps2=imu.accel_mps2[keep])
    res = fuse(replace(hills_car.inputs, imu=cut), FuseOptions(rate_hz=20.0, estimator="planar", smooth=True))
    assert res.info["level"]["grade"]["followed"], res.info["level"]["grade"]


def test_an_imu_yawed_against_its_calibration_does_not_make_a_flat_drive_climb():
    # 3 deg of yaw: the turns' centripetal acceleration on the IMU's forward axis read as a slow pitch that climbs
    # 0.146 m rms (0.047 once its share that follows the lateral acceleration is out, the sway's 0.047)
    case = simulate_case("drive", 45.0, seed=1, wheel_errors=False)
    c, s = np.cos(np.radians(3.0)), np.sin(np.radians(3.0))
    T = case.inputs.imu.T_base_imu.copy()
    T[:3, :3] = np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]]) @ T[:3, :3]
    res = fuse(replace(case.inputs, imu=replace(case.inputs.imu, T_base_imu=T)),
               FuseOptions(rate_hz=20.0, estimator="planar", smooth=True))
    g = res.info["level"]["grade"]
    assert g["climb_rms_m"] > 2.0 * g["sway_climb_rms_m"] and not g["followed"], g
    assert _ate(case, res) < 0.012  # 0.0074 m (0.073 followed)


@pytest.mark.parametrize("check, followed", [
    ({"measured": True, "scale": 1.0293, "scale_sigma": 0.0009}, True),  # a bad wheel's scale, measured
    ({"measured": False, "scale": 1.047, "scale_sigma": 0.0187}, True),  # a steady speed: unmeasured, near 1
    ({"measured": False, "scale": 0.8273, "scale_sigma": 0.0234}, False),  # groovy.bag: 7 sigmas off
    ({"measured": True, "scale": 0.83, "scale_sigma": 0.004}, False),  # measured, but no wheel is 17 % off
    (None, False),  # never checked
])
def test_the_grade_asks_that_the_imus_forward_axis_was_checked(check, followed):
    assert grade.forward_axis_checked(SimpleNamespace(wheel_check=check)) is followed
