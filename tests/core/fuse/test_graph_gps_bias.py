"""A consumer receiver's slow error beside odometry: the factor graph models it as a Gauss-Markov chain (a node
per fix), so the fused local shape stays the odometry's and GPS only anchors it; as white noise (the model before)
every fix bends the path. Wheels with a scale error beside odometry increments are loosened (or, optionally,
scaled by a state the odometry makes observable), so they cannot pull it either."""

from __future__ import annotations

from dataclasses import replace
from types import SimpleNamespace

import gtsam
import numpy as np
import pytest

from lio_cli.core.fuse import FuseOptions, GpsSeries, fuse
from lio_cli.core.fuse.graph import factors, gps, run
from lio_cli.core.fuse.graph.odom_spin import increment_sigma
from lio_cli.evaluation import EvalOptions, Trajectory, evaluate
from lio_cli.geometry import interpolate_poses, so3_exp
from lio_cli.simulation.fusion_case import OdomNoise, simulate_case


def ate(case, stamps, poses) -> float:
    ref = Trajectory(case.truth_stamps_ns, case.truth_poses, "gt")
    return evaluate(ref, Trajectory(stamps, poses, "est"), EvalOptions(align="se3")).stats["ape"]["trans"]["rmse"]


def slow_gps(case, seed: int = 4) -> GpsSeries:
    """Horizontal error 90 % Gauss-Markov (2.4 m, 60 s) plus 0.8 m white, as `lio simulate --gps-model consumer`;
    the covariance says 0.83 m (a third of the truth)."""
    rng = np.random.default_rng(seed)
    g = case.inputs.gps
    t = (g.stamps_ns - g.stamps_ns[0]) * 1e-9
    phi = np.exp(-np.diff(t, prepend=t[0]) / 60.0)
    b = np.zeros((len(t), 2))
    b[0] = rng.normal(0.0, 2.4, 2)
    for i in range(1, len(t)):
        b[i] = phi[i] * b[i - 1] + rng.normal(0.0, 2.4 * np.sqrt(1.0 - phi[i] ** 2), 2)
    z = interpolate_poses(case.truth_stamps_ns, case.truth_poses, g.stamps_ns)[:, :3, 3]
    z[:, :2] += b + rng.normal(0.0, 0.8, (len(t), 2))
    z[:, 2] += rng.normal(0.0, 1.5, len(t))
    cov = np.broadcast_to(np.diag([0.83**2, 0.83**2, 1.5**2]), (len(t), 3, 3)).copy()
    return GpsSeries(g.stamps_ns, z, cov, np.ones(len(t), bool))


@pytest.fixture(scope="module")
def case():
    odom = OdomNoise(position_sigma_m=0.003, rotation_sigma_rad=np.radians(0.05))  # a scan matcher's increments
    c = simulate_case("planar", 40.0, seed=2, wheels=False, odom=odom, gps_sigma_m=1.0)
    return replace(c, inputs=replace(c.inputs, gps=slow_gps(c)))


def test_a_slow_receiver_error_leaves_the_odometry_shape(case, monkeypatch):
    o = FuseOptions(estimator="ekf", rate_hz=20.0, smooth=True)
    odom = ate(case, case.inputs.odom.stamps_ns, case.inputs.odom.poses)
    res = fuse(case.inputs, o)
    assert res.info["smoother"]["fallback"] is None
    fused = ate(case, res.stamps_ns, res.poses)
    monkeypatch.setattr(gps, "GPS_BIAS_RATIO", 0.0)  # the fixes as white noise
    monkeypatch.setattr(run, "ODOM_SEED", False)  # from the filter's states (from the odometry's, Huber keeps them)
    w = fuse(case.inputs, o)
    white = ate(case, w.stamps_ns, w.poses)
    # measured: odometry 0.0328 m, fused 0.0328 m, white GPS 0.0380 m (0.60 m was the filter the guard fell
    # back to when it still judged GPS beside odometry by the filter's ratio)
    assert fused <= 1.2 * odom and white > 1.1 * fused


@pytest.fixture(scope="module")
def long_wheels():
    """Odometry from a file (no covariance: the default 0.02 m per pose) beside a slow GPS, so the filter takes
    it as increments, and wheels reading 3 % long."""
    odom = OdomNoise(position_sigma_m=0.003, rotation_sigma_rad=np.radians(0.05))
    case = simulate_case("planar", 40.0, seed=2, wheels=True, odom=odom, gps_sigma_m=1.0)
    od, w = case.inputs.odom, case.inputs.wheel
    od = replace(od, position_sigma_m=np.full(len(od), 0.02), rotation_sigma_rad=np.full(len(od), np.radians(0.5)))
    return replace(case, inputs=replace(case.inputs, gps=slow_gps(case), odom=od,
                                        wheel=replace(w, velocity_mps=w.velocity_mps * 1.03)))


def test_wheels_with_a_scale_error_do_not_pull_odometry_increments(long_wheels, monkeypatch):
    """Loosened beside odometry, long wheels leave the odometry's shape; at full weight they bend it."""
    case, o = long_wheels, FuseOptions(estimator="ekf", rate_hz=20.0, smooth=True)
    odom = ate(case, case.inputs.odom.stamps_ns, case.inputs.odom.poses)
    res = fuse(case.inputs, o)
    assert res.info["odom_mode"] == "delta" and res.info["smoother"]["fallback"] is None
    fused = ate(case, res.stamps_ns, res.poses)
    monkeypatch.setattr(factors, "ODOM_WHEEL_LOOSE_MODES", ())  # wheels at full weight beside increments
    full = fuse(case.inputs, o)
    old = ate(case, full.stamps_ns, full.poses)
    # measured: odometry 0.033 m, fused 0.036 m; full weight 0.090 m
    assert fused <= 1.25 * odom and old > 2.0 * odom


def _gps_vertical_sigmas(inputs, monkeypatch) -> tuple[np.ndarray, np.ndarray]:
    """(the graph's vertical GPS sigmas, the fixes' own) of one smoothed run, from its first chunk's graph."""
    seen = {}
    real = run.solve

    def spy(cg, K, first, seam, spans=None):
        seen["cg"], seen["K"] = cg, K
        return real(cg, K, first, seam, spans)

    monkeypatch.setattr(run, "solve", spy)
    fuse(inputs, FuseOptions(estimator="ekf", rate_hz=20.0, smooth=True))
    cg = seen["cg"]
    g = cg.build(0, min(seen["K"], 200))
    # the vertical fix: a 1D factor on a pose and its receiver-error node (``gps._fix_axes``)
    models = [g.at(i).noiseModel() for i in range(g.size())
              if isinstance(g.at(i), gtsam.CustomFactor) and g.at(i).dim() == 1]
    sig = [nm.noise().sigmas()[0] for nm in models]
    n = len(sig)
    return np.array(sig), cg.m.gps_v[:n]


def test_beside_odometry_the_gps_vertical_is_trusted_less(case, monkeypatch):
    """Beside odometry (its increments carry the height) the fixes' vertical sigma is ODOM_GPS_VERTICAL_SCALE
    times theirs; without odometry their own. Either way the vertical fix is tied to the receiver's slow error
    (a 1D factor on the pose and the fix's chain node: consumer altitudes wander by tens of metres)."""
    with_odom, own = _gps_vertical_sigmas(case.inputs, monkeypatch)
    assert len(with_odom) > 10
    np.testing.assert_allclose(with_odom, gps.ODOM_GPS_VERTICAL_SCALE * own)
    alone, own = _gps_vertical_sigmas(replace(case.inputs, odom=None), monkeypatch)
    np.testing.assert_allclose(alone, own)
    assert gps.ODOM_GPS_VERTICAL_SCALE > 1.0



def _odometry_file_case(scenario: str, seed: int, drift_yaw_rw: float):
    """Odometry as a file gives it beside a slow GPS (the default 0.02 m, 0.005 rad per pose: increments), a
    scan matcher's white noise 0.003 m, 0.005 deg and a yaw random walk ``drift_yaw_rw``."""
    odom = OdomNoise(position_sigma_m=0.003, rotation_sigma_rad=np.radians(0.005), drift_yaw_rw=drift_yaw_rw)
    case = simulate_case(scenario, 40.0, seed=seed, wheels=scenario == "planar", wheel_errors=False, odom=odom,
                         gps_sigma_m=1.0)
    od = case.inputs.odom
    od = replace(od, position_sigma_m=np.full(len(od), 0.02), rotation_sigma_rad=np.full(len(od), 0.005))
    return replace(case, inputs=replace(case.inputs, gps=slow_gps(case, seed), odom=od))


def test_the_odometry_increments_rotation_sigma_is_measured_against_the_gyro():
    """The increments' scatter about the gyro's (``odom_spin``) finds the simulated yaw random walk per 0.1 s
    increment (0.002 rad/sqrt(s): 0.63 mrad, with the poses' white 0.12 mrad: 0.64 mrad), which is looser than
    the default share, so the graph keeps it; a scan matcher's 0.0002 rad/sqrt(s) is measured far tighter."""
    o = FuseOptions(estimator="ekf", rate_hz=20.0, smooth=True)
    noisy = fuse(_odometry_file_case("drone", 3, 0.002).inputs, o).info["smoother"]
    assert noisy["odom_rotation_scatter_rad"] == pytest.approx(6.4e-4, rel=0.15)
    tight = fuse(_odometry_file_case("drone", 3, 0.0002).inputs, o).info["smoother"]
    # measured 0.146 mrad (the gyro's own white noise over 0.1 s is most of it)
    assert tight["odom_rotation_scatter_rad"] < 0.3 * noisy["odom_rotation_scatter_rad"]


@pytest.mark.parametrize("rate_hz, measured", [(0.1, False), (0.5, False), (1.0, True), (10.0, True)])
def test_low_rate_odometry_increments_are_not_measured_as_noise_free(rate_hz, measured):
    """A 10 s window's median bias taken from one or a few increments takes their scatter with it (one: exactly
    zero, so the floor, hundreds of times too tight): such windows measure nothing."""
    rng = np.random.default_rng(0)
    t = np.arange(0, 200 * 600) * 5_000_000  # 600 s of an exact gyro at 200 Hz, not turning
    ot = np.arange(int(590 * rate_hz)) * int(1e9 / rate_hz) + 1
    P = np.tile(np.eye(4), (len(ot), 1, 1))
    P[:, :3, :3] = [so3_exp(v) for v in rng.normal(0.0, 0.01, (len(ot), 3))]  # 0.01 rad a pose: 0.014 an increment
    prep = SimpleNamespace(odom=SimpleNamespace(stamps_ns=ot, poses=P), imu=SimpleNamespace(stamps_ns=t),
                           imu_w_b=np.zeros((len(t), 3)), imu_gap_ns=0)
    sigma = increment_sigma(prep, np.arange(len(ot)))
    if measured:
        assert sigma == pytest.approx(0.01 * np.sqrt(2), rel=0.2)
    else:
        assert sigma is None


def test_a_wheel_yaw_bias_does_not_turn_odometry_increments(monkeypatch):
    """Exact wheels but for a yaw rate 2 mrad/s off (a radius pair a little unequal): the gyro check passes
    them (their bias is taken as the gyro's), and at the wheels' own yaw sigma the graph turned the odometry's
    heading with them; loosened beside odometry as their speed is, the odometry's shape holds."""
    odom = OdomNoise(position_sigma_m=0.003, rotation_sigma_rad=np.radians(0.05))
    case = simulate_case("planar", 40.0, seed=2, wheels=True, wheel_errors=False, odom=odom, gps_sigma_m=1.0)
    od, w = case.inputs.odom, case.inputs.wheel
    od = replace(od, position_sigma_m=np.full(len(od), 0.02), rotation_sigma_rad=np.full(len(od), np.radians(0.5)))
    case = replace(case, inputs=replace(case.inputs, gps=slow_gps(case), odom=od,
                                        wheel=replace(w, yaw_rate_radps=w.yaw_rate_radps + 0.002)))
    o = FuseOptions(estimator="ekf", rate_hz=20.0, smooth=True)
    odom_ate = ate(case, case.inputs.odom.stamps_ns, case.inputs.odom.poses)
    res = fuse(case.inputs, o)
    assert res.info["odom_mode"] == "delta" and res.info["wheel_yaw_check"]["used"]
    fused = ate(case, res.stamps_ns, res.poses)
    monkeypatch.setattr(factors, "ODOM_YAW_SIGMA_SCALE", 1.0)  # the wheels' yaw at its own sigma
    full = fuse(case.inputs, o)
    old = ate(case, full.stamps_ns, full.poses)
    # measured: odometry 0.033 m, fused 0.024 m; the wheels' yaw at its own sigma 0.077 m
    assert fused <= odom_ate and old > 2.0 * odom_ate
