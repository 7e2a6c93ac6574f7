"""4-DoF (position + yaw) alignment against an independent closed form, hand cases and its limits."""

from __future__ import annotations

import numpy as np
import pytest

from lio_cli.errors import InputError
from lio_cli.evaluation import EvalOptions, Trajectory, align, evaluate
from lio_cli.evaluation.alignment import posyaw
from lio_cli.geometry import make_pose, so3_exp

CLOSED_FORM_TOL = 1e-9  # the target for agreement with an independent computation
EXACT = 1e-12


def _rz(rad: float) -> np.ndarray:
    return so3_exp(np.array([0.0, 0.0, rad]))


def _planar_umeyama(src: np.ndarray, dst: np.ndarray) -> tuple[float, np.ndarray]:
    """Independent closed form: 2D Umeyama (SVD of the x-y cross-covariance, no scale), z by the mean difference."""
    a, b = src[:, :2] - src[:, :2].mean(0), dst[:, :2] - dst[:, :2].mean(0)
    U, _, Vt = np.linalg.svd(b.T @ a)
    D = np.diag([1.0, np.sign(np.linalg.det(U @ Vt))])
    R2 = U @ D @ Vt
    t = np.empty(3)
    t[:2] = dst[:, :2].mean(0) - R2 @ src[:, :2].mean(0)
    t[2] = dst[:, 2].mean() - src[:, 2].mean()
    return float(np.arctan2(R2[1, 0], R2[0, 0])), t


def test_hand_case_three_points():
    src = np.array([[0.0, 0, 0], [1, 0, 0], [0, 1, 0]])
    dst = src @ _rz(np.deg2rad(30.0)).T + [1.0, 2.0, 3.0]
    R, t = posyaw(src, dst)
    np.testing.assert_allclose(R, _rz(np.deg2rad(30.0)), atol=EXACT)
    np.testing.assert_allclose(t, [1.0, 2.0, 3.0], atol=EXACT)


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_agrees_with_planar_umeyama_on_noisy_3d_points(seed):
    rng = np.random.default_rng(seed)
    src = rng.normal(0, 10, (300, 3))
    yaw = rng.uniform(-np.pi, np.pi)
    dst = src @ (so3_exp(np.array([0.02, -0.03, 0.0])) @ _rz(yaw)).T + rng.normal(0, 5, 3)  # a little roll/pitch too
    dst += rng.normal(0, 0.3, dst.shape)
    R, t = posyaw(src, dst)
    yaw_ref, t_ref = _planar_umeyama(src, dst)
    assert np.arctan2(R[1, 0], R[0, 0]) == pytest.approx(yaw_ref, abs=CLOSED_FORM_TOL)
    np.testing.assert_allclose(t, t_ref, rtol=0, atol=CLOSED_FORM_TOL)
    np.testing.assert_allclose(R[2], [0, 0, 1], atol=EXACT)  # a rotation about z only

    def cost(R_, t_):
        return float(np.sum((dst - (src @ R_.T + t_)) ** 2))

    best = cost(R, t)
    for d in (-1e-4, 1e-4):  # a turn either way, with its own best translation, costs more
        Rd = _rz(d) @ R
        assert cost(Rd, dst.mean(0) - Rd @ src.mean(0)) > best


def test_align_posyaw_on_first_n_poses_and_leaves_roll_pitch():
    rng = np.random.default_rng(3)
    n = 60
    t = np.linspace(0, 6, n)
    ref = np.stack([make_pose(_rz(0.3 * k), [5 * np.cos(k), 5 * np.sin(k), 0.1 * k]) for k in t])
    T1 = make_pose(_rz(0.7), [1.0, -2.0, 0.5])
    est = np.linalg.inv(T1) @ ref
    est[20:, :3, 3] += rng.normal(0, 1.0, (n - 20, 3))  # the tail is garbage: only the head may be fitted
    al = align(ref, est, "posyaw", n_align=20)
    assert al.mode == "posyaw" and al.n_used == 20 and al.scale == 1.0
    np.testing.assert_allclose(al.matrix, T1, atol=1e-10)
    # a tilted estimate: se3 removes the tilt, posyaw (4 DoF) does not
    tilt = make_pose(so3_exp(np.array([0.1, 0.0, 0.0])))
    tilted = tilt @ ref
    e_se3 = np.linalg.norm(align(ref, tilted, "se3").apply(tilted)[:, :3, 3] - ref[:, :3, 3], axis=1).max()
    e_4 = np.linalg.norm(align(ref, tilted, "posyaw").apply(tilted)[:, :3, 3] - ref[:, :3, 3], axis=1).max()
    assert e_se3 < 1e-9 and e_4 > 0.1


def test_degenerate_vertical_line_is_bad_input():
    pts = np.array([[1.0, 2.0, z] for z in range(5)])
    with pytest.raises(InputError) as err:
        posyaw(pts, pts + 1.0)
    assert str(err.value) == ("the trajectory is degenerate for posyaw alignment (no horizontal extent to fix the "
                              "yaw); use --align none")


def test_evaluate_posyaw_needs_two_matches():
    stamps = np.array([1, 2]) * 1_000_000_000
    ref = np.stack([make_pose(t=[0, 0, 0]), make_pose(t=[1, 0, 0])])
    est = np.stack([make_pose(_rz(np.pi / 2), [0, 0, 0]), make_pose(_rz(np.pi / 2), [0, 1, 0])])  # turned by 90 deg
    r = evaluate(Trajectory(stamps, ref, "gt"), Trajectory(stamps, est, "est"), EvalOptions(align="posyaw"))
    assert r.stats["ape"]["trans"]["max"] == pytest.approx(0.0, abs=EXACT)
    assert r.stats["ape"]["rot"]["max"] == pytest.approx(0.0, abs=1e-9)  # the yaw fit also undoes the heading
