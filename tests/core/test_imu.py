"""IMU propagation against analytic motion; start-up from a standing IMU."""

import numpy as np
import pytest

from lio_cli.config.odom import ImuNoise
from lio_cli.geometry import make_pose, so3_exp, so3_log
from lio_cli.core.imu import NavState, gravity_vector, propagate
from lio_cli.model.calibration import Extrinsics
from lio_cli.model.records import ImuBatch

G = 9.81
RATE_HZ = 200
POS_TOL_M = 1e-3
ROT_TOL_RAD = 1e-4


def _state(R=None):
    return NavState(0, np.eye(3) if R is None else R, np.zeros(3), np.zeros(3), np.zeros(3), np.zeros(3))


def _imu(duration_s, gyro_fn, accel_fn):
    t = np.arange(0, int(duration_s * RATE_HZ) + 1) / RATE_HZ
    stamps = np.round(t * 1e9).astype(np.int64)
    return ImuBatch("imu", stamps, np.array([gyro_fn(x) for x in t]), np.array([accel_fn(x) for x in t]))


IDENTITY = Extrinsics(np.eye(4), np.eye(4))


@pytest.mark.parametrize("omega", [np.array([0.0, 0.0, 3.0]), np.array([0.4, -0.7, 1.2])])
def test_constant_rotation_rate_matches_closed_form(omega):
    # rotating in place: gyro reads omega; accelerometer reads gravity rotated into the body
    imu = _imu(1.0, lambda t: omega, lambda t: so3_exp(omega * t).T @ np.array([0.0, 0.0, G]))
    prop = propagate(_state(), imu, 10**9, IDENTITY, g_world=gravity_vector(G))
    np.testing.assert_allclose(so3_log(prop.state.R.T @ so3_exp(omega * 1.0)), 0.0, atol=ROT_TOL_RAD)
    np.testing.assert_allclose(prop.state.p, 0.0, atol=POS_TOL_M)
    np.testing.assert_allclose(prop.state.v, 0.0, atol=POS_TOL_M)


def test_constant_acceleration_gives_parabola():
    a = np.array([1.0, 0.5, -0.2])
    imu = _imu(2.0, lambda t: np.zeros(3), lambda t: a + np.array([0.0, 0.0, G]))
    prop = propagate(_state(), imu, 2 * 10**9, IDENTITY, g_world=gravity_vector(G))
    np.testing.assert_allclose(prop.state.p, 0.5 * a * 4.0, atol=POS_TOL_M)
    np.testing.assert_allclose(prop.state.v, a * 2.0, atol=POS_TOL_M)
    # the knots trace the same parabola
    t = (prop.stamps_ns - prop.stamps_ns[0]) * 1e-9
    np.testing.assert_allclose(prop.poses[:, :3, 3], 0.5 * a * t[:, None] ** 2, atol=POS_TOL_M)


def test_lever_arm_and_rotated_imu_keep_spinning_base_in_place():
    # base spins about z at 2 rad/s around its own origin; the IMU sits 0.5 m ahead, rotated 90 deg about x
    w = np.array([0.0, 0.0, 2.0])
    r = np.array([0.5, 0.0, 0.0])
    R_bi = so3_exp(np.array([np.pi / 2, 0.0, 0.0]))
    ext = Extrinsics(make_pose(R_bi, r), np.eye(4))

    def accel(t):
        f_b = np.cross(w, np.cross(w, r)) + so3_exp(w * t).T @ np.array([0.0, 0.0, G])
        return R_bi.T @ f_b

    imu = _imu(1.5, lambda t: R_bi.T @ w, accel)
    prop = propagate(_state(), imu, int(1.5e9), ext, g_world=gravity_vector(G))
    np.testing.assert_allclose(prop.state.p, 0.0, atol=2 * POS_TOL_M)
    np.testing.assert_allclose(so3_log(prop.state.R.T @ so3_exp(w * 1.5)), 0.0, atol=ROT_TOL_RAD)


def test_bias_is_removed_before_integration():
    bg, ba = np.array([0.01, -0.02, 0.03]), np.array([0.1, 0.0, -0.05])
    imu = _imu(1.0, lambda t: bg, lambda t: np.array([0.0, 0.0, G]) + ba)
    s = _state()
    s.bg, s.ba = bg, ba
    prop = propagate(s, imu, 10**9, IDENTITY, g_world=gravity_vector(G))
    np.testing.assert_allclose(prop.state.p, 0.0, atol=1e-9)
    np.testing.assert_allclose(prop.state.R, np.eye(3), atol=1e-12)


def test_gap_in_imu_is_flagged():
    imu = _imu(1.0, lambda t: np.zeros(3), lambda t: np.array([0.0, 0.0, G]))
    keep = (imu.stamps_ns < 3 * 10**8) | (imu.stamps_ns > 6 * 10**8)
    gappy = ImuBatch("imu", imu.stamps_ns[keep], imu.gyro_radps[keep], imu.accel_mps2[keep])
    assert propagate(_state(), gappy, 10**9, IDENTITY).gap
    assert not propagate(_state(), imu, 10**9, IDENTITY).gap


def test_covariance_grows_with_time():
    imu = _imu(1.0, lambda t: np.zeros(3), lambda t: np.array([0.0, 0.0, G]))
    s = _state()
    s.P = np.eye(18) * 1e-9
    p_half = propagate(s, imu, 5 * 10**8, IDENTITY, noise=ImuNoise()).state.P
    p_full = propagate(s, imu, 10**9, IDENTITY, noise=ImuNoise()).state.P
    assert p_full[3, 3] > p_half[3, 3] > 1e-9  # position variance grows
    assert p_full[0, 0] > p_half[0, 0]


def test_a_gap_free_interval_is_one_imu_gap_ns_finds_no_gap_in():
    """``imu_gap_free`` may only spare ``imu_gap_ns`` where it would find nothing: over random sample spacings
    (dropouts, late starts, early ends) it is never True where the cost exceeds the limit, and True for an
    ordinary 200 Hz stream."""
    from lio_cli.core.imu import MAX_IMU_GAP_NS, imu_gap_free, imu_gap_ns

    rng = np.random.default_rng(5)
    free = 0
    for _ in range(3000):
        steps = rng.choice([5_000_000, 20_000_000, 26_000_000, 60_000_000], size=int(rng.integers(1, 40)),
                           p=[0.85, 0.05, 0.05, 0.05])
        stamps = np.cumsum(steps).astype(np.int64) + int(rng.integers(0, 10_000_000))
        t0 = int(rng.integers(0, 60_000_000))
        t1 = t0 + int(rng.integers(1, 150_000_000))
        if imu_gap_free(stamps, t0, t1):
            free += 1
            assert imu_gap_ns(stamps, t0, t1)[0] <= MAX_IMU_GAP_NS
    assert free > 300
    stamps = np.arange(0, 1_000_000_000, 5_000_000, dtype=np.int64)
    assert imu_gap_free(stamps, 100_000_000, 200_000_000)
    assert not imu_gap_free(stamps, 900_000_000, 1_100_000_000)  # no sample after the end: imu_gap_ns tells
    assert not imu_gap_free(np.delete(stamps, np.arange(30, 36)), 100_000_000, 200_000_000)  # a 35 ms hole


def test_running_integral_is_the_trapezoid_rule_and_skips_the_steps_asked():
    from lio_cli.core.imu import running_integral
    t = np.array([0.0, 0.5, 1.0, 3.0, 3.5])
    x = np.array([0.0, 1.0, 2.0, 4.0, 5.0])
    np.testing.assert_allclose(running_integral(t, x), [0.0, 0.25, 1.0, 7.0, 9.25])
    skip = np.array([False, False, True, False])  # the 2 s gap adds nothing
    np.testing.assert_allclose(running_integral(t, x, skip), [0.0, 0.25, 1.0, 1.0, 3.25])
    both = running_integral(t, np.column_stack([x, -x]))
    assert both.shape == (5, 2)
    np.testing.assert_allclose(both[:, 1], -running_integral(t, x))
    blocks = running_integral(t, np.ones((5, 3, 3)))  # samples of any shape: along the first axis
    np.testing.assert_allclose(blocks[:, 1, 2], t - t[0])
