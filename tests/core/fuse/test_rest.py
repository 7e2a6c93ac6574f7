"""A base at rest after the start (core/fuse/rest.py): a level drive made here, already moving at its first sample
(so nothing measures the gyro bias there), that stops from 12 to 18 s and drives on. At the stop the gyro reads
its bias; the filters take a zero turn rate and the graph zero motion, and the smoothers carry the bias back."""

from __future__ import annotations

from types import SimpleNamespace

import numpy as np
import pytest

from lio_cli.core.fuse import FuseInputs, FuseOptions, ImuSeries, WheelSeries, fuse
from lio_cli.core.fuse import api
from lio_cli.core.fuse.rest import EDGE_S, WINDOW_S, rest_spans
from lio_cli.evaluation import EvalOptions, Trajectory, evaluate
from lio_cli.simulation.motion import smoothstep, smoothstep_integral

NS = 1_000_000_000
T0 = 1_700_000_000 * NS
DURATION_S = 30.0
STOP = (12.0, 18.0)  # standing exactly still between these, braking and driving off over RAMP_S around them
RAMP_S = 3.0
GYRO_BIAS = np.array([0.0004, -0.0003, 0.003])  # z: 0.17 deg/s, 5 deg over the run if left unmeasured
ACCEL_BIAS = np.array([0.03, -0.02, 0.01])


def _motion(t: np.ndarray, stop: bool):
    """Distance along the road, speed and its derivative: 4 m/s from the first sample, stopping over STOP."""
    if not stop:
        return 4.0 * t, np.full_like(t, 4.0), np.zeros_like(t)
    a, b = STOP
    brake, go = smoothstep(t, a - RAMP_S, RAMP_S), smoothstep(t, b, RAMP_S)
    k = 1.0 - brake[0] + go[0]
    s = 4.0 * (t - smoothstep_integral(t, a - RAMP_S, RAMP_S) + smoothstep_integral(t, b, RAMP_S))
    return s, 4.0 * k, 4.0 * (go[1] - brake[1])


def _drive(stop: bool = True, seed: int = 3, wheel_scale: float = 1.0):
    """(inputs, truth) of a level drive along a winding road; turns only while it moves (the turn rate is the
    speed times the road's curvature). The wheels give their yaw rate (what tells rest from a turn on the spot);
    the runs below fuse their speed only (``USE``), so the gyro's bias is measured at the stop or nowhere."""
    rng = np.random.default_rng(seed)
    t = np.arange(0.0, DURATION_S, 0.005)
    s, v, dv = _motion(t, stop)
    curv = 0.08 * np.sin(2 * np.pi * s / 40.0)
    yaw_rate = v * curv
    dt = np.diff(t, prepend=t[0])
    yaw = np.cumsum(yaw_rate * dt)
    f = np.column_stack([dv, v * yaw_rate, np.full_like(t, 9.81)]) + ACCEL_BIAS + rng.normal(0, 0.01, (len(t), 3))
    gyro = np.column_stack([np.zeros_like(t), np.zeros_like(t), yaw_rate]) + GYRO_BIAS
    gyro += rng.normal(0.0, 0.0005, gyro.shape)
    st = T0 + np.round(t * NS).astype(np.int64)
    tw = t[::4]
    wheel = WheelSeries(st[::4], np.column_stack([v[::4] / wheel_scale, np.full_like(tw, np.nan),
                                                  np.full_like(tw, np.nan)]), yaw_rate[::4].copy())
    x, y = np.cumsum(v * np.cos(yaw) * dt), np.cumsum(v * np.sin(yaw) * dt)
    T = np.tile(np.eye(4), (len(t), 1, 1))
    T[:, 0, 0], T[:, 0, 1], T[:, 1, 0], T[:, 1, 1] = np.cos(yaw), -np.sin(yaw), np.sin(yaw), np.cos(yaw)
    T[:, 0, 3], T[:, 1, 3] = x, y
    return FuseInputs(imu=ImuSeries(st, gyro, f), wheel=wheel), Trajectory(st, T, "truth")


USE = {"imu": {"gyro", "accel"}, "wheel": {"speed"}}


def _ate(truth: Trajectory, res) -> float:
    est = Trajectory(res.stamps_ns, res.poses, "fused")
    return evaluate(truth, est, EvalOptions(max_diff_ns=1_000_000)).stats["ape"]["trans"]["rmse"]


def _without_rest(monkeypatch):
    monkeypatch.setattr(api.rest, "rest_spans", lambda prep, g: np.zeros((0, 2), np.int64))


def test_the_stop_is_found_and_the_moving_start_left_alone():
    inputs, _ = _drive()
    res = fuse(inputs, FuseOptions(rate_hz=50.0, use=USE))
    rest = res.info["rest"]
    assert rest["spans"] == 1
    (a, b), = (np.array(rest["span_ns"]) - T0) * 1e-9
    # inside the standstill, within a window of its ends (the windows start at the first sample)
    assert STOP[0] + EDGE_S - 1e-9 <= a <= STOP[0] + EDGE_S + WINDOW_S
    assert STOP[1] - EDGE_S - WINDOW_S <= b <= STOP[1] - EDGE_S + 1e-9
    kinds = res.reports["imu"].by_kind
    assert kinds["zero_rate"]["updates"] == pytest.approx((b - a) * 200, abs=2)


def test_no_stop_no_rest():
    inputs, _ = _drive(stop=False)
    assert fuse(inputs, FuseOptions(rate_hz=50.0, use=USE)).info["rest"] is None


@pytest.mark.parametrize("estimator, smooth, most", [
    ("auto", True, 0.05),    # the planar filter's RTS pass (measured 0.013 m with the stop, 0.36 without)
    ("auto", False, 0.25),   # the planar filter alone: the bias right from the stop on (0.13; 0.36 without)
    ("ekf", False, 0.2),     # the 3D filter (0.14; 0.26 without)
    ("ekf", True, 0.05),     # the factor graph (0.013; 0.25 without)
])
def test_a_stop_measures_the_gyro_bias(monkeypatch, estimator, smooth, most):
    inputs, truth = _drive()
    o = FuseOptions(estimator=estimator, smooth=smooth, rate_hz=50.0, use=USE)
    with_rest = _ate(truth, fuse(inputs, o))
    _without_rest(monkeypatch)
    without = _ate(truth, fuse(inputs, o))
    assert with_rest < most < without


@pytest.mark.parametrize("estimator, most", [("planar", 1e-6), ("ekf", 0.02)])
def test_a_filter_does_not_jump_when_the_robot_stops(monkeypatch, estimator, most):
    """Filtered, the rest updates reach the rates and the gyro bias only: the pose before and at the stop is the
    one without them (the smoothers move it, over the whole log). The 3D filter's wheel updates at rest then move
    it by their correlations with the bias, by a centimetre (a full update: 0.39 m; the planar filter 0.55)."""
    inputs, _ = _drive()
    o = FuseOptions(estimator=estimator, smooth=False, rate_hz=50.0, use=USE)
    res = fuse(inputs, o)
    a, b = res.info["rest"]["span_ns"][0]
    _without_rest(monkeypatch)
    ref = fuse(inputs, o)
    upto = res.stamps_ns <= b
    assert np.abs(res.poses[upto, :3, 3] - ref.poses[upto, :3, 3]).max() < most
    assert np.abs(res.poses[~upto, :3, 3] - ref.poses[~upto, :3, 3]).max() > 0.05  # driving on, the bias known


def test_the_graph_holds_the_base_still_at_rest():
    inputs, truth = _drive()
    res = fuse(inputs, FuseOptions(estimator="ekf", smooth=True, rate_hz=50.0, use=USE))
    assert res.info["smoother"]["kind"] == "factor_graph" and res.info["smoother"]["rest_intervals"] > 40
    a, b = (np.array(res.info["rest"]["span_ns"][0]))
    inside = (res.stamps_ns >= a) & (res.stamps_ns <= b)
    p = res.poses[inside, :3, 3]
    assert np.ptp(p, axis=0).max() < 0.005


class _Series(SimpleNamespace):
    def __len__(self) -> int:
        return len(self.stamps_ns)


def _prep(**kw):
    """The fields ``rest_spans`` reads, at 200 Hz over 10 s: the wheels turning for the first second, then at
    rest throughout unless ``kw`` says otherwise."""
    t = T0 + np.arange(0, 10 * NS, 5_000_000, dtype=np.int64)
    tw = t[::4]
    imu = _Series(stamps_ns=t, accel_mps2=np.tile([0.0, 0.0, 9.81], (len(t), 1)))
    speed = np.where(tw < T0 + NS, 1.0, 0.0)
    wheel = _Series(stamps_ns=tw, velocity_mps=np.column_stack([speed, np.zeros((len(tw), 2))]),
                            yaw_rate_radps=np.zeros(len(tw)))
    fields = dict(imu=imu, imu_w_b=np.tile([0.0, 0.0, 0.001], (len(t), 1)), wheel=wheel, odom=None, t0_ns=t[0],
                  use={"imu": {"gyro", "accel"}, "wheel": {"speed"}})
    fields.update(kw)
    return SimpleNamespace(**fields)


def _span_s(p) -> list[tuple[float, float]]:
    return [(round((a - T0) * 1e-9, 3), round((b - T0) * 1e-9, 3)) for a, b in rest_spans(p, 9.81)]


def test_rest_needs_the_wheels_still_not_turning_on_the_spot():
    assert _span_s(_prep()) == [(1.0 + EDGE_S, 9.995 - EDGE_S)]
    p = _prep()
    p.wheel.yaw_rate_radps[p.wheel.stamps_ns > T0 + NS] = 0.05  # a slow turn on the spot: the speed is zero
    assert _span_s(p) == []
    p = _prep()
    p.wheel.velocity_mps[:, 0] = 0.2  # at constant velocity the IMU reads as at rest
    assert _span_s(p) == []
    p = _prep()
    p.wheel.velocity_mps[p.wheel.stamps_ns > T0 + NS, 1] = 0.5  # a holonomic base strafing
    assert _span_s(p) == []
    p = _prep()
    p.wheel.yaw_rate_radps[:] = np.nan  # no yaw rate: a turn on the spot would read so
    assert _span_s(p) == []


def test_rest_by_the_odometry_without_wheels():
    t = T0 + np.arange(0, 10 * NS, 100_000_000, dtype=np.int64)
    T = np.tile(np.eye(4), (len(t), 1, 1))
    T[:, 0, 3] = np.minimum((t - T0) * 1e-9, 1.0)  # 1 m/s for a second, then still
    odom = _Series(stamps_ns=t, poses=T)
    p = _prep(wheel=None, odom=odom, use={"imu": {"gyro", "accel"}, "odom": {"pose"}})
    assert _span_s(p) == [(1.0 + EDGE_S, 9.995 - EDGE_S)]
    assert _span_s(_prep(wheel=None, use={"imu": {"gyro"}})) == []  # neither: at constant velocity it reads so


def test_the_start_rest_is_the_standing_start_s():
    p = _prep()
    p.wheel.velocity_mps[:, 0] = 0.0  # at rest from the first window: ``initial_state`` measured it
    assert _span_s(p) == []


def test_a_wheel_driver_starting_late_is_still_the_start():
    p = _prep()
    p.wheel.velocity_mps[:, 0] = 0.0
    late = p.wheel.stamps_ns >= T0 + 2 * NS  # at rest throughout, the wheels heard from 2 s on
    p.wheel = _Series(stamps_ns=p.wheel.stamps_ns[late], velocity_mps=p.wheel.velocity_mps[late],
                      yaw_rate_radps=p.wheel.yaw_rate_radps[late])
    assert _span_s(p) == []


def test_the_complementary_filter_claims_no_rest():
    inputs, _ = _drive()
    assert fuse(inputs, FuseOptions(estimator="complementary", rate_hz=50.0, use=USE)).info["rest"] is None


def test_an_imu_gap_is_not_rest():
    p = _prep()
    keep = (p.imu.stamps_ns < T0 + 4 * NS) | (p.imu.stamps_ns > T0 + 6 * NS)
    p = _prep(imu=_Series(stamps_ns=p.imu.stamps_ns[keep], accel_mps2=p.imu.accel_mps2[keep]),
              imu_w_b=p.imu_w_b[keep])
    spans = _span_s(p)
    assert len(spans) == 2 and spans[0][1] < 4.0 and spans[1][0] > 6.0
