"""The ground's normal in the LiDAR frame from scans at rest, against the plane the points were drawn on."""

from __future__ import annotations

import numpy as np
import pytest

from lio_cli.core.calibration.lidar_ground import fit_lidar_ground
from lio_cli.errors import InputError
from lio_cli.geometry import so3_exp


def scene(rng, R_world_lidar, height_m, slope=None, n=20000):
    """Points in the LiDAR frame: level ground (or, ``slope`` (rad about the world x for y > 0), a second plane
    on one side), a wall and a parked car's box, with 1.5 cm of range-like noise."""
    r = np.sqrt(rng.uniform(2.5**2, 30.0**2, n))
    a = rng.uniform(-np.pi, np.pi, n)
    g = np.column_stack([r * np.cos(a), r * np.sin(a), np.zeros(n)])
    if slope is not None:
        side = g[:, 1] > 0
        g[side, 2] = np.tan(slope) * g[side, 1]
    wall = np.column_stack([rng.uniform(-20, 20, n // 4), np.full(n // 4, 8.0), rng.uniform(0, 6, n // 4)])
    box = np.column_stack([rng.uniform(4, 8, n // 8), rng.uniform(-3, -1.5, n // 8), rng.uniform(0, 1.5, n // 8)])
    world = np.concatenate([g, wall, box]) + rng.normal(0, 0.015, (n + n // 4 + n // 8, 3))
    return (world - [0.0, 0.0, height_m]) @ R_world_lidar  # rows: R^T (p - t)


def test_a_tilted_lidar_s_ground_normal_and_height_come_back():
    rng = np.random.default_rng(1)
    R = so3_exp(np.radians([2.0, -3.0, 40.0]))  # the LiDAR rolled, pitched and turned on the vehicle
    g = fit_lidar_ground(scene(rng, R, 1.8), np.array([0.0, 0.0, 1.0]))
    truth = R.T @ [0.0, 0.0, 1.0]
    err = np.arccos(np.clip(g.normal @ truth, -1, 1))
    assert np.degrees(err) < 0.02
    assert err <= 3 * g.sigma_rad
    assert g.height_m == pytest.approx(1.8, abs=0.01)
    assert g.sectors == 8 and g.inliers > 15000
    assert np.abs(g.covariance_rad2 @ g.normal).max() < 1e-9 * np.trace(g.covariance_rad2)  # none about the normal


def test_uneven_ground_widens_the_1_sigma_to_cover_the_error():
    rng = np.random.default_rng(2)
    R = so3_exp(np.radians([0.0, 0.0, 10.0]))
    g = fit_lidar_ground(scene(rng, R, 1.9, slope=np.radians(0.6)), np.array([0.0, 0.0, 1.0]))
    err = np.arccos(np.clip(g.normal @ (R.T @ [0.0, 0.0, 1.0]), -1, 1))
    assert np.degrees(err) > 0.05  # the sloped half pulls the fit
    assert err <= 3 * g.sigma_rad  # the sectors' disagreement says so
    flat = fit_lidar_ground(scene(np.random.default_rng(2), R, 1.9), np.array([0.0, 0.0, 1.0]))
    assert g.sigma_rad > 5 * flat.sigma_rad


def test_scans_without_ground_below_are_refused_with_the_reason():
    rng = np.random.default_rng(3)
    above = rng.uniform(-10, 10, (5000, 3)) + [0.0, 0.0, 12.0]
    with pytest.raises(InputError, match=r"^ground plane: 0 points below the LiDAR within 40 m \(need 200\): "
                                         r"the scans do not show the ground$"):
        fit_lidar_ground(above, np.array([0.0, 0.0, 1.0]))
