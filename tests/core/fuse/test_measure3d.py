"""Jacobians of the 3D model against numerical differentiation on the error state.

For a measurement, ``r(x [+] d) - r(x) = -H d`` to first order; for a process step,
``f(x [+] d) [-] f(x) = F d``. A sign or frame slip in any block fails these.
"""

from __future__ import annotations

import numpy as np
import pytest

from lio_cli.core.fuse import measure3d as m3
from lio_cli.core.fuse.state3d import Layout, boxminus, boxplus, cv_step, gyro_step, ins_step, new_state, pose
from lio_cli.geometry import inv_pose, make_pose, so3_exp

EPS = 1e-6
JAC_TOL = 2e-5  # first-order agreement at EPS steps (second-order terms ~ EPS * |state|)


def random_state(rng: np.random.Generator, L: Layout) -> np.ndarray:
    x = new_state(so3_exp(rng.normal(size=3)), rng.normal(size=3), rng.normal(size=3), 0.05 * rng.normal(size=3),
                  0.1 * rng.normal(size=3))
    if L.clone:
        x[21:30] = so3_exp(rng.normal(size=3)).reshape(9)
        x[30:33] = x[9:12] - rng.normal(size=3) * 0.3
    return x


def numeric(fn, x: np.ndarray, L: Layout) -> np.ndarray:
    base = fn(x.copy())
    cols = []
    for k in range(L.n):
        d = np.zeros(L.n)
        d[k] = EPS
        xp = x.copy()
        boxplus(xp, d, L)
        cols.append((fn(xp) - base) / EPS)
    return np.column_stack(cols)


MEASUREMENTS = {
    "orientation": lambda x, L, z: m3.orientation(x, z[:3, :3], np.eye(3), L),
    "body_velocity": lambda x, L, z: m3.body_velocity(x, np.zeros(3), [0, 1, 2], np.ones(3), L),
    "yaw_rate_gyro": lambda x, L, z: m3.yaw_rate(x, 0.3, 1.0, np.array([0.1, 0.2, 0.4]), 0.0, L),
    "pose_absolute": lambda x, L, z: m3.pose_absolute(x, z, 1.0, 1.0, L),
    "pose_delta": lambda x, L, z: m3.pose_delta(x, z, 1.0, 1.0, L),
    "position": lambda x, L, z: m3.position(x, z[:3, 3], np.eye(3), L),
}


# the gyro form of the yaw rate exists only with a gyro model
CASES = [(n, m) for n in sorted(MEASUREMENTS) for m in ("ins", "cv") if not (n == "yaw_rate_gyro" and m == "cv")]


@pytest.mark.parametrize(("name", "model"), CASES)
def test_measurement_jacobians(name, model):
    rng = np.random.default_rng(7)
    L = Layout(model, clone=True)
    x = random_state(rng, L)
    # linearised at the prediction (zero rotation residual, where H = I on the rotation error is exact)
    z = pose(x) if name != "pose_delta" else inv_pose(make_pose(x[21:30].reshape(3, 3), x[30:33])) @ pose(x)
    fn = MEASUREMENTS[name]
    _, H, _ = fn(x, L, z)
    J = numeric(lambda xx: fn(xx, L, z)[0], x, L)
    np.testing.assert_allclose(-J, H, atol=JAC_TOL)


def test_cv_yaw_rate_jacobian():
    L = Layout("cv", clone=False)
    x = random_state(np.random.default_rng(1), L)
    _, H, _ = m3.yaw_rate(x, 0.3, 1.0, None, 0.0, L)
    J = numeric(lambda xx: m3.yaw_rate(xx, 0.3, 1.0, None, 0.0, L)[0], x, L)
    np.testing.assert_allclose(-J, H, atol=JAC_TOL)


STEPS = {
    "ins": lambda x, L: ins_step(x, 0.01, np.array([0.3, -0.2, 0.5]), np.array([0.4, 0.1, 9.7]), L,
                                 np.array([0.0, 0.0, -9.81])),
    "gyro": lambda x, L: gyro_step(x, 0.01, np.array([0.3, -0.2, 0.5]), L),
    "cv": lambda x, L: cv_step(x, 0.01, L),
}
STEP_TOL = 5e-5  # F uses J_r(w dt) ~ I: an O(|w| dt^2 / 2) = 2.6e-5 approximation in the bias block


@pytest.mark.parametrize("model", sorted(STEPS))
def test_process_jacobians(model):
    L = Layout(model, clone=False)
    x = random_state(np.random.default_rng(3), L)
    step = STEPS[model]
    x1 = x.copy()
    F = step(x1, L)
    cols = []
    for k in range(L.n):
        d = np.zeros(L.n)
        d[k] = EPS
        xp = x.copy()
        boxplus(xp, d, L)
        step(xp, L)
        cols.append(boxminus(xp, x1, L) / EPS)
    np.testing.assert_allclose(np.column_stack(cols), F, atol=STEP_TOL)


def test_boxplus_boxminus_round_trip():
    L = Layout("ins", clone=True)
    rng = np.random.default_rng(11)
    x = random_state(rng, L)
    d = rng.normal(size=L.n) * 0.3
    y = x.copy()
    boxplus(y, d, L)
    np.testing.assert_allclose(boxminus(y, x, L), d, atol=1e-12)
    np.testing.assert_allclose(pose(y)[:3, :3] @ pose(y)[:3, :3].T, np.eye(3), atol=1e-12)
