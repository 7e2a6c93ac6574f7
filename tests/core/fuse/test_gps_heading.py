"""Start heading from the GPS fixes: 2D rotation of the GPS-free path onto them."""

from __future__ import annotations

import numpy as np

from lio_cli.core.fuse.gps_heading import yaw_onto


def test_yaw_onto_recovers_a_known_rotation_with_an_offset():
    rng = np.random.default_rng(0)
    path = np.cumsum(rng.normal(size=(50, 2)), axis=0)
    a = 2.5
    R = np.array([[np.cos(a), -np.sin(a)], [np.sin(a), np.cos(a)]])
    fixes = path @ R.T + [100.0, -40.0]
    np.testing.assert_allclose(yaw_onto(path, fixes), a, atol=1e-12)


def test_yaw_onto_straight_line():
    path = np.column_stack([np.arange(10.0), np.zeros(10)])
    fixes = np.column_stack([np.zeros(10), np.arange(10.0)])  # the path runs north in ENU
    np.testing.assert_allclose(yaw_onto(path, fixes), np.pi / 2, atol=1e-12)


def test_yaw_velocity_onto_finds_the_heading_and_the_start_velocity_a_zero_velocity_pass_missed():
    """The pass started at rest on a base moving at 4 m/s: Kabsch alone is thrown off; the fit with the
    velocity and a constant acceleration (a tilt) as unknowns is not."""
    from lio_cli.core.fuse.gps_heading import yaw_velocity_onto
    t = np.linspace(0.0, 3.0, 16)
    path = np.c_[0.5 * np.sin(2.0 * t) + 0.1 * t**2, 0.3 * (1.0 - np.cos(2.0 * t))]  # start frame, from rest
    v0 = np.array([4.0, 0.5])  # start frame
    yaw = np.radians(130.0)
    R = np.array([[np.cos(yaw), -np.sin(yaw)], [np.sin(yaw), np.cos(yaw)]])
    fixes = (path + np.outer(t, v0)) @ R.T + np.outer(t**2, [0.2, -0.1]) + [5.0, -3.0]
    fixes += np.random.default_rng(1).normal(0.0, 0.05, fixes.shape)
    got, w = yaw_velocity_onto(path, fixes, t)
    assert abs(np.degrees(got) - 130.0) < 5.0
    assert abs(np.degrees(yaw_onto(path, fixes)) - 130.0) > 20.0  # what the zero-velocity pass gave
    assert np.allclose(w, R @ v0, atol=0.3)
