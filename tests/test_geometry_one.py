"""Single-rotation exp/log (the per-sample filter path) against the scipy-backed array versions."""

from __future__ import annotations

import numpy as np
import pytest

from lio_cli import geometry as g

ROT_TOL = 1e-12


@pytest.mark.parametrize("angle", [0.0, 1e-12, 1e-7, 1e-4, 0.3, 1.0, 2.5, np.pi - 1e-3])
def test_exp_one_and_log_one_match_scipy(angle):
    rng = np.random.default_rng(int(angle * 1e6) % 1000)
    axis = rng.normal(size=3)
    phi = axis / np.linalg.norm(axis) * angle
    R = g.so3_exp_one(phi)
    np.testing.assert_allclose(R, g.so3_exp(phi), atol=ROT_TOL)
    np.testing.assert_allclose(g.so3_log_one(R), g.so3_log(R), atol=1e-9 if angle > 3 else ROT_TOL)


def test_log_one_near_pi_falls_back_correctly():
    phi = np.array([0.0, 0.0, np.pi - 1e-9])
    np.testing.assert_allclose(np.abs(g.so3_log_one(g.so3_exp(phi))), np.abs(phi), atol=1e-6)


def test_pose_from_floats_is_bit_identical_to_the_array_version():
    """The message decoders' one-pose path: the same bits as pose_from_xyz_quat, over quaternions of any norm."""
    rng = np.random.default_rng(7)
    for _ in range(2000):
        q = rng.normal(size=4) * 10 ** rng.uniform(-3, 3)
        xyz = rng.normal(size=3) * 100
        q = q / float(np.linalg.norm(q))
        np.testing.assert_array_equal(g.pose_from_xyz_quat_one(tuple(xyz.tolist()), tuple(q.tolist())),
                                      g.pose_from_xyz_quat(xyz, q))
