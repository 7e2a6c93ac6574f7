"""The wheels' yaw rate weighed against the gyro from the data (core/fuse/wheel_yaw.py), on a level drive made here
that is already moving at the start (the gyro's bias cannot be learned standing): exact wheels give the heading,
so do wheels whose yaw scale the fit measures (divided out), wheels whose scale it cannot measure are left out,
a slip's yaw rates are rejected and counted."""

from __future__ import annotations

import numpy as np
import pytest

from lio_cli.core.fuse import FuseInputs, FuseOptions, ImuSeries, WheelSeries, fuse
from lio_cli.core.fuse.graph import wheels
from lio_cli.core.fuse.report import NOTE_REASONS, REJECT_REASONS
from lio_cli.evaluation import EvalOptions, Trajectory, evaluate
from lio_cli.simulation.sensors import smooth_window

NS = 1_000_000_000
T0 = 1_700_000_000 * NS
DURATION_S = 30.0
GYRO_BIAS_Z = 0.004  # rad/s: 0.12 rad of heading over the run where nothing measures it


def _case(yaw_scale: float = 1.0, slip: tuple[float, float, float] | None = None, seed: int = 0,
          speed_share: float = 0.0):
    """(inputs, truth) of a winding drive at 1.5-4.5 m/s from the first sample; wheels exact but for ``yaw_scale``
    (their yaw rate over the true one), ``speed_share`` (rad/m: unequal radii turn a straight drive) and a
    ``slip`` (start s, length s, extra yaw rate rad/s)."""
    rng = np.random.default_rng(seed)
    t = np.arange(0.0, DURATION_S, 0.005)
    w = 2 * np.pi / 7.0
    v, dv = 3.0 + 1.5 * np.sin(w * t), 1.5 * w * np.cos(w * t)
    yaw_rate = 0.3 * np.sin(2 * np.pi * t / 11.0) + 0.1
    f = np.column_stack([dv, v * yaw_rate, np.full_like(t, 9.81)]) + rng.normal(0.0, 0.01, (len(t), 3))
    gyro = np.column_stack([np.zeros_like(t), np.zeros_like(t), yaw_rate + GYRO_BIAS_Z])
    gyro += rng.normal(0.0, 0.0005, gyro.shape)
    st = T0 + np.round(t * NS).astype(np.int64)
    tw = t[::4]  # 50 Hz
    wheel_yaw = yaw_rate[::4] * yaw_scale + speed_share * v[::4]
    if slip is not None:
        wheel_yaw = wheel_yaw + slip[2] * smooth_window(tw, slip[0], slip[1])
    wheel = WheelSeries(st[::4], np.column_stack([v[::4], np.full_like(tw, np.nan), np.full_like(tw, np.nan)]),
                        wheel_yaw)
    dt = np.diff(t, prepend=t[0])
    yaw = np.cumsum(yaw_rate * dt)
    x, y = np.cumsum(v * np.cos(yaw) * dt), np.cumsum(v * np.sin(yaw) * dt)
    T = np.tile(np.eye(4), (len(t), 1, 1))
    T[:, 0, 0], T[:, 0, 1], T[:, 1, 0], T[:, 1, 1] = np.cos(yaw), -np.sin(yaw), np.sin(yaw), np.cos(yaw)
    T[:, 0, 3], T[:, 1, 3] = x, y
    return FuseInputs(imu=ImuSeries(st, gyro, f), wheel=wheel), Trajectory(st, T, "truth")


def _errors(truth: Trajectory, res) -> tuple[float, float]:
    """(ATE m, RMS heading error rad) after an SE(3) fit."""
    ev = evaluate(truth, Trajectory(res.stamps_ns, res.poses, "est"), EvalOptions(align="se3"))
    R_ref, R_est = ev.association.ref.poses[:, :3, :3], ev.est_aligned[:, :3, :3]
    dyaw = np.arctan2(R_ref[:, 1, 0], R_ref[:, 0, 0]) - np.arctan2(R_est[:, 1, 0], R_est[:, 0, 0])
    dyaw = (dyaw + np.pi) % (2 * np.pi) - np.pi
    return ev.stats["ape"]["trans"]["rmse"], float(np.sqrt(np.mean((dyaw - dyaw.mean()) ** 2)))


@pytest.mark.parametrize("smooth", [False, True])
def test_exact_wheels_give_the_heading_and_the_gyro_bias_on_a_moving_start(smooth):
    inputs, truth = _case()
    res = fuse(inputs, FuseOptions(smooth=smooth, rate_hz=20.0))
    old = fuse(inputs, FuseOptions(smooth=smooth, rate_hz=20.0, weigh_wheel_yaw=False))
    assert res.estimator == old.estimator == "planar"
    check = res.info["wheel_yaw_check"]
    assert check["used"] and abs(check["scale_off"]) < 0.001, check
    assert "yaw_rate" in res.info["use"]["wheel"] and "yaw_rate" not in old.info["use"]["wheel"]
    ate, yaw = _errors(truth, res)
    ate_old, yaw_old = _errors(truth, old)
    # the gyro alone, its bias unknown: measured ATE 0.44 m, heading 0.034 rad RMS; with the wheels' yaw rate
    # 0.011 m, 0.0011 rad
    assert ate_old > 0.3 and yaw_old > 0.02
    assert ate < 0.03 and yaw < 0.003
    rep = res.reports["wheel"]
    assert rep.by_kind["wheel_yaw_rate"]["updates"] > 0.9 * len(inputs.wheel.stamps_ns)
    assert rep.notes["yaw_noise_estimated"] > 0 and "yaw_noise_estimated" in NOTE_REASONS
    # the first wheel message's period starts before the IMU's first sample: never weighed, left out
    assert rep.rejected["yaw_unchecked"] == check["unchecked_samples"] == 1 and "yaw_unchecked" in REJECT_REASONS


def test_a_yaw_scale_off_by_a_radius_error_is_measured_and_divided_out():
    inputs, truth = _case(yaw_scale=1 / 1.03)  # both radii 3 % large: the yaw rate reads 2.9 % low
    res = fuse(inputs, FuseOptions(rate_hz=20.0))
    old = fuse(inputs, FuseOptions(rate_hz=20.0, weigh_wheel_yaw=False))
    check = res.info["wheel_yaw_check"]
    assert check["used"], check
    assert abs(check["scale_off"] - (1 - 1 / 1.03)) < 5 * check["scale_off_sigma"] < 0.001, check
    assert "divided out" in check["why"] and "yaw_rate" in res.info["use"]["wheel"]
    ate, yaw = _errors(truth, res)
    # measured: as good as exact wheels (0.011 m, 0.0011 rad); the gyro alone 0.44 m, 0.034 rad
    assert ate < 0.03 and yaw < 0.003
    assert _errors(truth, old)[0] > 0.3


def test_a_yaw_rate_that_follows_the_speed_leaves_the_wheels_out():
    inputs, _ = _case(yaw_scale=1 / 1.03, speed_share=0.004)  # unequal radii: 0.012-0.018 rad/s of false turning
    res = fuse(inputs, FuseOptions(rate_hz=20.0))
    check = res.info["wheel_yaw_check"]
    assert not check["used"] and "yaw_rate" not in res.info["use"]["wheel"], check
    # the residual's share of the speed, with the gyro's scale fitted (gyro - wheel: the wheels' share negated)
    assert abs(check["speed_share_radpm"] + 0.004) < 0.0005 and check["speed_share_sigma"] < 0.0002, check
    assert check["why"].startswith("the wheels' yaw rate follows their speed (+0.004")
    exact = fuse(_case(yaw_scale=1 / 1.03)[0], FuseOptions(rate_hz=20.0)).info["wheel_yaw_check"]
    assert exact["used"] and abs(exact["speed_share_radpm"]) < 5 * exact["speed_share_sigma"], exact


@pytest.mark.parametrize("yaw_scale", [0.0, -1.0, 0.5])
def test_a_zero_flipped_or_halved_yaw_rate_is_no_scale_to_divide_out(yaw_scale):
    inputs, _ = _case(yaw_scale=yaw_scale)  # a driver that fills angular.z with zeros, a sign error, a gear ratio
    res = fuse(inputs, FuseOptions(rate_hz=20.0))
    check = res.info["wheel_yaw_check"]
    assert not check["used"] and "yaw_rate" not in res.info["use"]["wheel"], check
    assert "beyond 10%: not a radius or baseline error" in check["why"]
    assert "deg/s" not in check["why"]
    assert np.isfinite(res.poses).all()


@pytest.mark.parametrize("yaw_scale, hint", [
    (np.pi / 180, " (the gyro reads 57.3x the wheels: is the IMU's angular velocity in deg/s?)"),
    (180 / np.pi, " (the wheels read 57.3x the gyro: is their yaw rate in deg/s?)")])
def test_a_yaw_rate_in_degrees_is_named(yaw_scale, hint):
    inputs, _ = _case(yaw_scale=yaw_scale)  # the wheels' yaw rate over the gyro's: a radian against a degree
    check = fuse(inputs, FuseOptions(rate_hz=20.0)).info["wheel_yaw_check"]
    assert not check["used"] and check["why"].endswith(hint), check


def test_a_yaw_scale_the_fit_cannot_measure_leaves_the_wheels_out():
    inputs, _ = _case(yaw_scale=1 / 1.03)
    rng = np.random.default_rng(5)  # a skid-steered base's yaw rate: noise of a few tenths of a rad/s
    noisy = inputs.wheel.yaw_rate_radps + rng.normal(0.0, 0.4, len(inputs.wheel.stamps_ns))
    inputs = FuseInputs(imu=inputs.imu, wheel=WheelSeries(inputs.wheel.stamps_ns, inputs.wheel.velocity_mps, noisy))
    res = fuse(inputs, FuseOptions(rate_hz=20.0))
    check = res.info["wheel_yaw_check"]
    assert not check["used"] and 2 * check["scale_off_sigma"] > 0.005, check
    assert check["why"].startswith("the wheels' yaw scale is") and "not measured to 0.5%" in check["why"]
    assert "yaw_rate" not in res.info["use"]["wheel"]
    assert "wheel_yaw_rate" not in res.reports["wheel"].by_kind


def test_a_slip_s_yaw_rates_are_rejected_and_counted():
    inputs, truth = _case(slip=(12.0, 1.5, 0.5))
    res = fuse(inputs, FuseOptions(rate_hz=20.0))
    check = res.info["wheel_yaw_check"]
    assert check["used"], check
    rep = res.reports["wheel"]
    # the burst's 1.5 s at 50 Hz (75 samples) and its widened edges, no more
    assert 60 <= rep.rejected["yaw_slip"] == check["far_samples"] <= 110 and "yaw_slip" in REJECT_REASONS
    ate, yaw = _errors(truth, res)
    assert ate < 0.03 and yaw < 0.003


def test_an_explicit_selection_is_kept():
    inputs, _ = _case()
    res = fuse(inputs, FuseOptions(rate_hz=20.0, use={"imu": {"gyro", "accel"}, "wheel": {"speed"}}))
    assert res.info["wheel_yaw_check"] is None and "yaw_rate" not in res.info["use"]["wheel"]


def test_the_factor_graph_takes_the_heading_from_the_wheels(monkeypatch):
    inputs, truth = _case()
    res = fuse(inputs, FuseOptions(smooth=True, estimator="ekf", rate_hz=20.0))
    assert res.info["smoother"]["kind"] == "factor_graph" and res.info["smoother"]["fallback"] is None
    ate, yaw = _errors(truth, res)
    monkeypatch.setattr(wheels.YawTrack, "of", classmethod(lambda cls, *a: None))  # the graph without its yaw factor
    ate_without, yaw_without = _errors(truth, fuse(inputs, FuseOptions(smooth=True, estimator="ekf", rate_hz=20.0)))
    # measured: 0.009 m, 0.0005 rad; without the factor 0.16 m, 0.0125 rad (the 3D filter's start alone)
    assert ate < 0.03 and yaw < 0.002
    assert ate_without > 0.08 and yaw_without > 0.006
