"""Start-up: attitude from gravity, standing detection, and what a steady turn must not be taken for."""

from __future__ import annotations

import numpy as np

from lio_cli.core.fuse.initial import without_yaw
from lio_cli.geometry import gravity_aligned_rotation
from lio_cli.geometry import so3_exp, yaw_of

ROT_TOL = 1e-12


def test_level_rotation_puts_the_specific_force_on_world_z_with_zero_yaw():
    R_true = so3_exp(np.array([0.2, -0.3, 0.0]))
    R_true = without_yaw(R_true)
    f_base = R_true.T @ np.array([0.0, 0.0, 9.81])
    R = gravity_aligned_rotation(f_base)
    np.testing.assert_allclose(R @ f_base, [0.0, 0.0, 9.81], atol=1e-12)
    np.testing.assert_allclose(yaw_of(R), 0.0, atol=ROT_TOL)
    np.testing.assert_allclose(R, R_true, atol=1e-12)


def test_level_rotation_upside_down():
    R = gravity_aligned_rotation(np.array([0.0, 0.0, -9.81]))
    np.testing.assert_allclose(R @ np.array([0.0, 0.0, -1.0]), [0.0, 0.0, 1.0], atol=ROT_TOL)


def test_without_yaw_keeps_tilt():
    R = so3_exp(np.array([0.0, 0.0, 1.2])) @ so3_exp(np.array([0.1, 0.05, 0.0]))
    Rn = without_yaw(R)
    np.testing.assert_allclose(yaw_of(Rn), 0.0, atol=ROT_TOL)
    np.testing.assert_allclose(Rn.T @ [0, 0, 1.0], R.T @ [0, 0, 1.0], atol=ROT_TOL)  # same "up" in base
