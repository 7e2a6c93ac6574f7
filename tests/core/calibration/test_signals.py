"""Gyro orientation and exact integrals of piecewise-linear signals against closed forms."""

import numpy as np

from lio_cli.core.calibration.signals import GyroOrientation, PiecewiseLinear, prefix_products, second_divided_difference
from lio_cli.geometry import so3_exp, so3_log

ROT_TOL_RAD = 1e-9
INTEGRAL_TOL = 1e-9


def test_prefix_products_match_a_loop():
    rng = np.random.default_rng(0)
    steps = so3_exp(rng.normal(0.0, 0.5, (37, 3)))
    expect = [steps[0]]
    for s in steps[1:]:
        expect.append(expect[-1] @ s)
    np.testing.assert_allclose(prefix_products(steps), np.array(expect), atol=1e-12)


def test_constant_rate_gyro_integrates_to_the_exact_rotation_between_samples():
    w = np.array([0.3, -1.1, 2.0])
    stamps = np.arange(0, 2_000_000_001, 5_000_000, dtype=np.int64)
    g = GyroOrientation(stamps, np.tile(w + 0.01, (len(stamps), 1)), bias_radps=np.full(3, 0.01))
    t = np.array([0.0, 0.0123, 1.0, 1.9971])  # between samples too
    np.testing.assert_allclose(so3_log(np.swapaxes(so3_exp(w * t[:, None]), 1, 2) @ g.at(t)), 0.0, atol=ROT_TOL_RAD)
    inc = g.increments(np.array([0.2]), np.array([0.7]))[0]
    np.testing.assert_allclose(so3_log(inc), w * 0.5, atol=ROT_TOL_RAD)


def test_lidar_stamps_map_onto_the_imu_clock_by_subtracting_the_offset():
    stamps = np.arange(0, 1_000_000_001, 10_000_000, dtype=np.int64) + 5_000_000_000
    g = GyroOrientation(stamps, np.zeros((len(stamps), 3)))
    np.testing.assert_allclose(g.relative_s(np.array([5_500_000_000]), 0.02), [0.48])


def test_integrals_of_a_linear_signal_are_exact():
    t = np.sort(np.random.default_rng(1).uniform(0.0, 10.0, 400))
    f = np.column_stack([2.0 + 3.0 * t, -1.0 + 0.5 * t])  # linear: the piecewise-linear model is exact
    pl = PiecewiseLinear(t, f)
    ta, tb, tc = np.array([1.0, 2.5]), np.array([1.7, 4.0]), np.array([3.1, 6.0])
    mean_expect = np.column_stack([2.0 + 1.5 * (ta + tc), -1.0 + 0.25 * (ta + tc)])
    np.testing.assert_allclose(pl.interval_mean(ta, tc), mean_expect, atol=INTEGRAL_TOL)
    # a linear signal's hat average is its value at the hat's centroid (ta + tb + tc) / 3
    c = (ta + tb + tc) / 3.0
    np.testing.assert_allclose(pl.hat_average(ta, tb, tc), np.column_stack([2.0 + 3.0 * c, -1.0 + 0.5 * c]),
                               atol=INTEGRAL_TOL)


def test_second_divided_difference_of_a_cubic_is_the_hat_average_of_its_acceleration():
    # x = t^3: x'' = 6 t; DD over (ta, tb, tc) = 6 * centroid
    ta, tb, tc = np.array([0.3]), np.array([0.55]), np.array([1.2])
    dd = second_divided_difference(ta**3, tb**3, tc**3, ta, tb, tc)
    np.testing.assert_allclose(dd, 6.0 * (ta + tb + tc) / 3.0, atol=INTEGRAL_TOL)
    t = np.linspace(0.0, 2.0, 2001)
    pl = PiecewiseLinear(t, (6.0 * t)[:, None])
    np.testing.assert_allclose(pl.hat_average(ta, tb, tc)[:, 0], dd, atol=1e-9)


def test_rotating_vectors_matches_the_orientation_matrices():
    rng = np.random.default_rng(1)
    stamps = np.arange(0, 2_000_000_000, 5_000_000)
    go = GyroOrientation(stamps, rng.normal(0, 2, (len(stamps), 3)))
    t = rng.uniform(-0.1, 2.1, 5000)  # some outside the samples: clamped alike
    v = rng.normal(0, 5, (5000, 3))
    np.testing.assert_allclose(go.rotate(t, v), np.einsum("nij,nj->ni", go.at(t), v), atol=1e-13)
