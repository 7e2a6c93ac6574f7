"""A consumer GPS beside IMU + wheels (no odometry): its slow error (metres, correlated over a minute) must not
bend a good dead reckoning (``shape``), and a track the fixes contradict beyond that error is told apart."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from lio_cli.core.fuse import FuseOptions, GpsSeries, fuse
from lio_cli.core.fuse import agreement, api, shape
from lio_cli.evaluation import EvalOptions, Trajectory, evaluate
from lio_cli.geometry import interpolate_poses
from lio_cli.simulation.fusion_case import simulate_case

NS = 1_000_000_000


def ate(case, res) -> float:
    ref = Trajectory(case.truth_stamps_ns, case.truth_poses, "gt")
    return evaluate(ref, Trajectory(res.stamps_ns, res.poses, "est"), EvalOptions(align="se3")).stats["ape"]["trans"]["rmse"]


def slow_error(t_s: np.ndarray, seed: int, sigma: float = 2.4, white: float = 0.8) -> np.ndarray:
    """(N,2) a consumer receiver's horizontal error: Gauss-Markov ``sigma`` (60 s) plus ``white``."""
    rng = np.random.default_rng(seed)
    phi = np.exp(-np.diff(t_s, prepend=t_s[0]) / 60.0)
    b = np.zeros((len(t_s), 2))
    b[0] = rng.normal(0.0, sigma, 2)
    for i in range(1, len(t_s)):
        b[i] = phi[i] * b[i - 1] + rng.normal(0.0, sigma * np.sqrt(1.0 - phi[i] ** 2), 2)
    return b + rng.normal(0.0, white, (len(t_s), 2))


@pytest.fixture(scope="module")
def case():
    """30 s of the planar robot with exact wheels and a GPS whose covariance claims 0.3 m (its white part is 0.8 m,
    its slow one 2.4 m): the filter raises the claim, so the shape test applies."""
    return _slow_gps_case(0.3)


def _slow_gps_case(claim_m: float):
    """30 s of the planar robot, exact wheels, fixes with a 2.4 m slow error whose covariance claims ``claim_m``."""
    c = simulate_case("planar", 30.0, seed=3, wheel_errors=False, gps_sigma_m=1.0)
    g = c.inputs.gps
    z = interpolate_poses(c.truth_stamps_ns, c.truth_poses, g.stamps_ns)[:, :3, 3]
    z[:, :2] += slow_error((g.stamps_ns - g.stamps_ns[0]) * 1e-9, seed=5)
    z[:, 2] += np.random.default_rng(6).normal(0.0, 1.5, len(z))
    cov = np.broadcast_to(np.diag([claim_m**2, claim_m**2, 1.5**2]), (len(z), 3, 3)).copy()
    return replace(c, inputs=replace(c.inputs, gps=GpsSeries(g.stamps_ns, z, cov, np.ones(len(z), bool))))


def test_a_slow_gps_error_does_not_make_imu_and_wheels_worse(case, monkeypatch):
    o = FuseOptions(rate_hz=20.0, smooth=True)
    without = ate(case, fuse(replace(case.inputs, gps=None), o))
    res = fuse(case.inputs, o)
    assert res.info["gps_shape"]["consistent"] and res.info["world_yaw_from"] == "gps"
    assert res.reports["gps"].notes["noise_raised"] >= shape.OPTIMISTIC_SHARE * len(case.inputs.gps)
    with_gps = ate(case, res)
    monkeypatch.setattr(shape, "applies", lambda prep, estimator: False)  # the fixes fused as they come (the model before)
    bent = ate(case, api.fuse(case.inputs, o))
    # measured: without GPS 0.001 m, with it the same, the fixes fused as they come 0.21 m
    assert with_gps <= 1.05 * without + 0.002 and bent > 0.05


@pytest.fixture(scope="module")
def honest():
    """White 3 m fixes whose covariance says 3 m beside exact wheels."""
    c = simulate_case("planar", 30.0, seed=3, wheel_errors=False, gps_sigma_m=1.0)
    g = c.inputs.gps
    z = interpolate_poses(c.truth_stamps_ns, c.truth_poses, g.stamps_ns)[:, :3, 3]
    z[:, :2] += np.random.default_rng(2).normal(0.0, 3.0, (len(z), 2))
    cov = np.broadcast_to(np.diag([9.0, 9.0, 9.0]), (len(z), 3, 3)).copy()
    return replace(c, inputs=replace(c.inputs, gps=GpsSeries(g.stamps_ns, z, cov, np.ones(len(z), bool))))


def test_an_honest_claim_is_fused_as_it_is(honest):
    """Nothing to raise and wheels the IMU did not verify (their yaw rate not weighed): GPS shapes the track."""
    res = fuse(honest.inputs, FuseOptions(rate_hz=20.0, smooth=True, weigh_wheel_yaw=False))
    assert "gps_shape" not in res.info and res.info["smoother"]["kind"] == "factor_graph"


def test_beside_wheels_the_imu_verified_an_honest_claim_is_tested_too(honest):
    """Speed scale measured, yaw rate agreeing with the gyro: the GPS-free track is tested against the fixes
    whatever the filter's innovations say."""
    o = FuseOptions(rate_hz=20.0, smooth=True)
    res = fuse(honest.inputs, o)
    assert res.info["wheel_yaw_check"]["used"] and res.info["gps_shape"]["consistent"]
    fused = fuse(honest.inputs, replace(o, weigh_wheel_yaw=False))
    # measured: 0.0016 m against the GPS-fused graph's 0.008 m
    assert ate(honest, res) < 0.5 * ate(honest, fused)


@pytest.fixture(scope="module")
def unraised():
    """The slow error of ``case`` (2.4 m, 60 s) under a claim its white part (0.8 m) matches: the filter's
    innovations raise too few fixes to call it optimistic."""
    return _slow_gps_case(0.8)


def test_fixes_scattered_beyond_their_claim_have_the_shape_tested(unraised):
    """Wheels whose yaw rate is not weighed (so not verified; their speed scale the IMU measured) and a claim the
    filter kept: the fixes' scatter about the GPS-free track (metres against a 0.8 m claim) says the receiver has
    more error than it claims, so the shape is tested."""
    o = FuseOptions(rate_hz=20.0, smooth=True, weigh_wheel_yaw=False)
    res = fuse(unraised.inputs, o)
    assert res.reports["gps"].notes.get("noise_raised", 0) < shape.OPTIMISTIC_SHARE * len(unraised.inputs.gps)
    test = res.info["gps_shape"]
    assert test["claim_exceeded"] and test["consistent"] and test["drift_chi2"] <= shape.CHI2_1_99
    without = ate(unraised, fuse(replace(unraised.inputs, gps=None), o))
    # measured: without GPS 0.0013 m, with it the same (the test skipped, fused as they come: 0.096 m)
    assert ate(unraised, res) <= 1.05 * without + 0.002


def test_a_heading_drift_the_chi_square_misses_is_told_apart():
    """340 m at 7.5 m/s whose heading drifts 2.5 mrad/s (a gyro bias the wheels did not check): 3 m of bend the
    slow error's chi-square takes (it spreads over 225 fixes' white noise), the drift test does not; the true
    track passes both."""
    t = np.arange(0.0, 45.0, 0.2)
    true = np.column_stack([7.5 * t, 20.0 * np.sin(t / 8.0)])
    fixes = true + slow_error(t, seed=1)
    step = np.diff(true, axis=0, prepend=true[:1])
    a = 0.0025 * t
    bent = np.cumsum(np.column_stack([np.cos(a) * step[:, 0] - np.sin(a) * step[:, 1],
                                      np.sin(a) * step[:, 0] + np.cos(a) * step[:, 1]]), axis=0)
    C = shape.error_covariance(t, 2.5)
    dof = 2 * len(t) - 3
    for track, drifts in ((true, False), (bent, True)):
        th, _, chi2 = shape.rigid_fit(track, fixes, C)
        assert chi2 <= dof + shape.QUANTILE_Z * np.sqrt(2 * dof)
        removed, rate = shape.heading_drift(track, fixes, C, t, th)
        assert (removed > shape.CHI2_1_99) == drifts
    assert abs(rate - 0.0025) < 0.001


@pytest.mark.parametrize("check, backed", [
    ({"verified": True, "slips": 3, "scale": 1.0268, "scale_sigma": 0.0043, "scale_applied": True}, True),
    ({"verified": False, "slips": 0, "scale": 0.9836, "scale_sigma": 0.0105, "scale_applied": False}, True),
    ({"verified": False, "slips": 0, "scale": 0.9585, "scale_sigma": 0.0116, "scale_applied": False}, False),
    ({"verified": False, "slips": 3, "scale": 1.0052, "scale_sigma": 0.0121, "scale_applied": False}, False),
    (None, False),
])
def test_the_scatter_opens_the_test_only_where_the_imu_backs_the_wheel_speed(check, backed):
    """Measured scale, or no slip and the accelerometer's rough scale within 99 % of the one used (the matrix's
    seed 8 rovers: exact wheels at a steady speed 0.9836 +- 0.0105 backed, a rotated IMU's 0.9585 +- 0.0116 not;
    three slips nothing bridged not); nothing checked (the 3D filter chosen), not."""
    assert agreement.wheel_speed_backed(check) is backed


def test_a_track_the_fixes_contradict_is_told_apart():
    """300 m at 7 m/s with a 6 % scale error: 19 m over the run, far beyond a 2.5 m receiver error (3 %, 9 m,
    is not: chi-square 505 against 516); the true track
    with the same fixes passes, turned and shifted (the fit finds the heading and position)."""
    t = np.arange(0.0, 45.0, 0.2)
    true = np.column_stack([7.0 * t, 30.0 * np.sin(t / 10.0)])
    fixes = true + slow_error(t, seed=1)
    th, shift = np.radians(40.0), np.array([12.0, -5.0])
    R = np.array([[np.cos(th), -np.sin(th)], [np.sin(th), np.cos(th)]])
    C = shape.error_covariance(t, 2.5)
    a, s, chi2 = shape.rigid_fit((true - shift) @ R, fixes, C)  # the track in another frame
    dof = 2 * len(t) - 3
    assert abs(a - th) < np.radians(1.0) and np.linalg.norm(s - shift) < 4.0  # the receiver's mean error
    assert chi2 <= dof + shape.QUANTILE_Z * np.sqrt(2 * dof)
    _, _, chi2_long = shape.rigid_fit(1.06 * true, fixes, C)
    assert chi2_long > dof + shape.QUANTILE_Z * np.sqrt(2 * dof)


def test_a_track_scaled_by_an_unmeasured_radius_is_told_apart():
    """340 m at 7.5 m/s against an honest receiver (0.8 m white, as claimed): a track 2 % long (a wheel radius the
    accelerometer did not measure) passes the chi-square under three times the claim, the scale test does not; the
    true track passes both."""
    t = np.arange(0.0, 45.0, 0.2)
    true = np.column_stack([7.5 * t, 20.0 * np.sin(t / 8.0)])
    fixes = true + np.random.default_rng(3).normal(0.0, 0.8, true.shape)
    long = true[0] + 1.02 * (true - true[0])
    C = shape.error_covariance(t, shape.TRUE_OVER_CLAIMED * 0.8)
    dof = 2 * len(t) - 3
    for track, scaled in ((true, False), (long, True)):
        th, _, chi2 = shape.rigid_fit(track, fixes, C)
        assert chi2 <= dof + shape.QUANTILE_Z * np.sqrt(2 * dof)
        removed, off = shape.track_scale(track, fixes, C, th)
        assert (removed > shape.CHI2_1_99) == scaled
    assert abs(off + 0.02) < 0.005  # the fit shrinks the long track back
