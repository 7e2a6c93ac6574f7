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
