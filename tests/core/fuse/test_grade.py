"""The planar output's height over hills: its path climbs the grade the IMU's slow pitch shows (``level.grade``,
``heave.climb``) where that climb stands out of what the body's sway alone would climb; on flat ground it stays
about a level."""

from __future__ import annotations

from types import SimpleNamespace

import numpy as np
import pytest

import lio_cli.core.fuse.level as level
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


def test_a_car_over_gentle_hills_climbs_them(monkeypatch):
    # 0.3 m high, 100 m apart (1.1 deg at the steepest): the planar filter's level height missed them by 0.19 m
    case = simulate_case("drive", 45.0, seed=1, wheel_errors=False, hills=(0.3, 100.0))
    res = fuse(case.inputs, FuseOptions(rate_hz=20.0, estimator="planar", smooth=True))
    grade = res.info["level"]["grade"]
    assert grade["followed"] and grade["climb_rms_m"] > 3.0 * grade["sway_climb_rms_m"], grade
    assert res.info["heave"]["model"] == "accelerometer about the grade's climb"
    monkeypatch.setattr(level, "GRADE_SIGNIFICANCE", np.inf)
    flat = fuse(case.inputs, FuseOptions(rate_hz=20.0, estimator="planar", smooth=True))
    assert not flat.info["level"]["grade"]["followed"]
    assert _ate(case, res) < 0.3 * _ate(case, flat), (_ate(case, res), _ate(case, flat))  # 0.044 against 0.180 m


def test_a_flat_drive_keeps_its_level():
    case = simulate_case("drive", 45.0, seed=1, wheel_errors=False)
    res = fuse(case.inputs, FuseOptions(rate_hz=20.0, estimator="planar", smooth=True))
    grade = res.info["level"]["grade"]
    # the sway's slow leak climbs less than the sway itself (0.029 against 0.044 m): no grade
    assert not grade["followed"] and grade["climb_rms_m"] < 1.5 * grade["sway_climb_rms_m"], grade
    assert res.info["heave"]["model"] == "accelerometer about a level"
    assert _ate(case, res) < 0.012  # 0.0063 m


@pytest.mark.parametrize("check, followed", [
    ({"measured": True, "scale": 1.0293, "scale_sigma": 0.0009}, True),  # a bad wheel's scale, measured
    ({"measured": False, "scale": 1.047, "scale_sigma": 0.0187}, True),  # a steady speed: unmeasured, near 1
    ({"measured": False, "scale": 0.8273, "scale_sigma": 0.0234}, False),  # groovy.bag: 7 sigmas off
    (None, False),  # never checked
])
def test_the_grade_asks_that_the_imus_forward_axis_was_checked(check, followed):
    assert level._forward_axis_checked(SimpleNamespace(wheel_check=check)) is followed
