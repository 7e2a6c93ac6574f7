"""Wheel increments beside odometry in the factor graph: the wheels' speed scale found, slips left out and counted
(``graph.wheels``), on a short simulated drive whose wheels read 5 % long and slip for 2 s."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from lio_cli.core.fuse import FuseOptions, fuse
from lio_cli.core.fuse.graph import factors, wheels
from lio_cli.evaluation import EvalOptions, Trajectory, evaluate
from lio_cli.simulation.fusion_case import OdomNoise, simulate_case

LONG = 1.05  # the wheels read this times the true speed: the scale to find is 1 / LONG
SCALE_TOL = 0.005
NS = 1_000_000_000


def ate(case, stamps, poses) -> float:
    ref = Trajectory(case.truth_stamps_ns, case.truth_poses, "gt")
    return evaluate(ref, Trajectory(stamps, poses, "est"), EvalOptions(align="se3")).stats["ape"]["trans"]["rmse"]


@pytest.fixture(scope="module")
def long_slipping_wheels():
    """A 30 s drive, odometry as `lio odom` makes it (consecutive poses close, the file's default sigma) and wheels
    5 % long with the case's slip (25 % / 10 % on the two wheels for 2 s from 12 s)."""
    case = simulate_case("drive", 30.0, seed=3, wheels=True, wheel_errors=True,
                         odom=OdomNoise(position_sigma_m=0.003, drift_position_rw=0.01))
    w, od = case.inputs.wheel, case.inputs.odom
    od = replace(od, position_sigma_m=np.full(len(od), 0.02), rotation_sigma_rad=np.full(len(od), 0.005))
    return replace(case, inputs=replace(case.inputs, odom=od, wheel=replace(w, velocity_mps=w.velocity_mps * LONG)))


def test_the_scale_is_found_and_the_slip_left_out(long_slipping_wheels):
    case = long_slipping_wheels
    res = fuse(case.inputs, FuseOptions(estimator="ekf", rate_hz=20.0, smooth=True))
    sm = res.info["smoother"]
    assert res.info["odom_mode"] == "pose" and sm["fallback"] is None
    w = sm["wheel"]
    # measured: 0.95222 (truth 0.95238; the case's radii 1.01 / 0.99 average to 1)
    assert abs(w["scale"][0] - 1.0 / LONG) < SCALE_TOL
    # the 2 s slip is 20 intervals of 0.1 s, one window either side is left out with it: measured 40
    slip = w["rejected"]["slip"]
    assert 20 <= slip["count"] <= 50 and "slip" in slip["why"]
    assert w["increments"] >= 200  # the rest kept (measured 260)
    fused, odom = ate(case, res.stamps_ns, res.poses), ate(case, case.inputs.odom.stamps_ns, case.inputs.odom.poses)
    # measured: 0.0422 against 0.0433 (the old loosened wheels: 0.0422 too; beside odometry poses the poses decide)
    assert fused <= 0.99 * odom


def test_the_old_loosened_wheels_report_no_scale(long_slipping_wheels, monkeypatch):
    monkeypatch.setattr(factors, "WHEEL_SCALE", False)
    sm = fuse(long_slipping_wheels.inputs, FuseOptions(estimator="ekf", rate_hz=20.0, smooth=True)).info["smoother"]
    assert "wheel" not in sm


def _line(n: int, speed_mps: float = 1.5, dt_s: float = 0.1):
    """Keyframe stamps and states along x at a constant speed."""
    kt = np.arange(n + 1, dtype=np.int64) * int(dt_s * NS)
    p = np.zeros((n + 1, 3))
    p[:, 0] = speed_mps * dt_s * np.arange(n + 1)
    return kt, {"R": np.tile(np.eye(3), (n + 1, 1, 1)), "p": p}


def test_gate_finds_the_scale_and_the_slip_windows():
    rng = np.random.default_rng(0)
    kt, s = _line(200)
    ks = np.arange(200)
    true = np.diff(s["p"], axis=0) + rng.normal(0.0, 0.002, (200, 3))
    dps = true / 1.03  # wheels reading 3 % short
    dps[105:115, 0] *= 1.3  # a 1 s slip: 30 % too fast, inside window 10 and 11
    g = wheels.gate(kt, s, ks, dps)
    assert abs(g.scale - 1.03) < 0.003
    windows = set((kt[g.rejected] // wheels.WINDOW_NS).tolist())
    assert {10, 11} <= windows and windows <= {9, 10, 11, 12}  # the slip's and one on either side


def test_gate_without_slips_leaves_everything_in():
    rng = np.random.default_rng(1)
    kt, s = _line(200)
    dps = np.diff(s["p"], axis=0) * 0.97 + rng.normal(0.0, 0.002, (200, 3))
    g = wheels.gate(kt, s, np.arange(200), dps)
    assert abs(g.scale - 1.0 / 0.97) < 0.003 and len(g.rejected) == 0


def test_gate_at_rest_keeps_the_scale_one():
    kt, s = _line(50, speed_mps=0.0)
    g = wheels.gate(kt, s, np.arange(50), np.zeros((50, 3)))
    assert g.scale == 1.0 and len(g.rejected) == 0


@pytest.mark.parametrize("odom_scale", [1.0, 0.85, 0.5, 1000.0, -1.0])
def test_an_odometry_off_the_wheels_by_more_than_a_radius_error_is_told(long_slipping_wheels, odom_scale):
    """Odometry in millimetres written as metres (or halved) was followed without a word; wheels 5 % long against
    it (0.952) and 0.81 stay within a radius error's 20 %."""
    od = long_slipping_wheels.inputs.odom
    poses = od.poses.copy()
    poses[:, :3, 3] *= odom_scale
    inputs = replace(long_slipping_wheels.inputs, odom=replace(od, poses=poses))
    notes = fuse(inputs, FuseOptions(estimator="ekf", rate_hz=20.0)).info["notes"]
    told = [n for n in notes if n.startswith("odometry: its path ")]
    if abs(odom_scale / LONG - 1.0) <= 0.2:
        assert told == []
        return
    if odom_scale < 0:  # reversed: a sign, not a scale
        head, _, tail = told[0].partition("x their distance)")
        assert len(told) == 1 and head.startswith("odometry: its path runs against the wheels' speed (")
        assert tail == ": the wheels' speed has its sign reversed, or the odometry's forward axis is not the base's"
        assert float(head.rsplit("(", 1)[1]) == pytest.approx(odom_scale / LONG, rel=0.002)
        return
    head, _, tail = told[0].partition("x the wheels' distance")
    assert len(told) == 1 and tail == (", beyond a wheel's radius error (20%): check its units and scale (the fused "
                                       "trajectory follows it)")
    assert float(head.rsplit(" ", 1)[1]) == pytest.approx(odom_scale / LONG, rel=0.002)


def _straight(scale: float, odom_sigma_m: float = 0.002):
    """30 s at 2 m/s with a sway in speed: wheels at 50 Hz reading ``scale`` times it, odometry at 10 Hz."""
    from lio_cli.core.fuse.inputs import PoseSeries, WheelSeries

    rng = np.random.default_rng(3)
    tw = np.arange(0.0, 30.0, 0.02)
    speed = 2.0 + 0.5 * np.sin(tw / 3.0)
    x = np.concatenate([[0.0], np.cumsum(0.5 * (speed[1:] + speed[:-1]) * 0.02)])
    to = tw[::5]
    P = np.tile(np.eye(4), (len(to), 1, 1))
    P[:, 0, 3] = x[::5] + rng.normal(0.0, odom_sigma_m, len(to))
    ns = (1_700_000_000 + tw * 1e9).astype(np.int64)
    wheel = WheelSeries(ns, np.column_stack([scale * speed, np.zeros_like(tw), np.zeros_like(tw)]), np.zeros_like(tw))
    return wheel, PoseSeries(ns[::5], P)


def test_the_wheels_agree_with_the_odometry_within_its_standard_error():
    agrees, why = wheels.odometry_agreement(*_straight(1.0))
    assert agrees and why.startswith("the odometry's path 1.0000x the wheels' distance (+- 0.000")
    agrees, why = wheels.odometry_agreement(*_straight(1.01))  # a radius 1 % long, no slip
    assert not agrees and why.startswith("the odometry's path 0.9901x the wheels' distance")
    wheel, odom = _straight(1.0)
    agrees, why = wheels.odometry_agreement(wheel, replace(odom, stamps_ns=odom.stamps_ns[:3], poses=odom.poses[:3]))
    assert (agrees, why) == (False, "too little motion to weigh the wheels against the odometry")
