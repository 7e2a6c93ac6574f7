"""The planar output's height (``heave``) and the planar smoother's re-integration and turn-rate walk."""

from __future__ import annotations

import numpy as np

from lio_cli.core.fuse.heave import CROSSOVER_HZ, _solve
from lio_cli.core.fuse.rts_planar import reintegrated
from lio_cli.core.fuse.planar_model import MIN_TURN_WALK, TH, V, W, X, Y, predict, turn_rate_walk


def test_heights_follow_a_heave_above_the_crossover_and_not_a_drift_below():
    t = np.arange(0.0, 60.0, 0.02)
    level = np.sqrt(0.02) / (2.0 * np.pi * CROSSOVER_HZ) ** 2
    for f_hz, gain in ((0.5, (0.98, 1.01)), (1.3, (0.995, 1.005))):  # the heave: recovered to 2 % and 0.5 %
        z_true = 0.05 * np.sin(2.0 * np.pi * f_hz * t)
        z = _solve(t, -(2.0 * np.pi * f_hz) ** 2 * z_true, 1.0, level)
        mid = slice(500, -500)  # the ends lack half their neighbours
        k = float(z[mid] @ z_true[mid] / (z_true[mid] @ z_true[mid]))
        assert gain[0] <= k <= gain[1], (f_hz, k)
    # a constant acceleration error (a bias the high-pass left) would climb 0.5 * 0.01 * 60^2 = 18 m: held level
    z = _solve(t, np.full(len(t), 0.01), 1.0, level)
    assert np.abs(z).max() < 0.02


def test_reintegration_removes_the_half_step_lag_of_the_model():
    dt, a = 0.005, 4.0  # m/s^2 straight ahead from rest
    t_ns = (np.arange(401) * dt * 1e9).astype(np.int64)
    x = np.zeros((len(t_ns), 6))
    for k in range(1, len(t_ns)):  # the filter's model, fed the exact speed: its x lags by a * t * dt / 2
        x[k] = x[k - 1]
        predict(x[k], dt, 6)
        x[k, V] = a * k * dt
    t = t_ns * 1e-9
    assert abs(x[-1, X] - 0.5 * a * t[-1] ** 2) > 0.5 * a * t[-1] * dt * 0.9
    r = reintegrated(t_ns, x)
    np.testing.assert_allclose(r[:, X], 0.5 * a * t**2, atol=1e-9)
    # on an arc, speed 2 m/s and turn rate 0.5 rad/s: the circle of radius 4 m
    x = np.zeros((len(t_ns), 6))
    x[:, V], x[:, W] = 2.0, 0.5
    r = reintegrated(t_ns, x)
    np.testing.assert_allclose(r[:, TH], 0.5 * t, atol=1e-12)
    np.testing.assert_allclose(np.c_[r[:, X], r[:, Y]], np.c_[4.0 * np.sin(0.5 * t), 4.0 * (1 - np.cos(0.5 * t))],
                               atol=1e-6)


def test_turn_rate_walk_is_what_the_gyro_shows():
    rng = np.random.default_rng(3)
    t_ns = (np.arange(40_000) * 5e6).astype(np.int64)  # 200 s at 200 Hz
    noise = rng.normal(0.0, 0.003, len(t_ns))
    assert turn_rate_walk(t_ns, noise) == MIN_TURN_WALK  # white noise alone: the turn rate does not change
    walk = np.cumsum(rng.normal(0.0, 0.05 * np.sqrt(0.005), len(t_ns)))  # a 0.05 rad/s^2/sqrt(Hz) random walk
    q = turn_rate_walk(t_ns, walk + noise)
    assert 0.045 < q < 0.055
