"""RTS smoother: on a linear-Gaussian model it must equal the batch least-squares solution; on simulated
odometry + IMU it must beat the filter."""

from __future__ import annotations

import numpy as np
import pytest

from lio_cli.core.fuse import FuseOptions, fuse
from lio_cli.core.fuse.kalman import KnotLog, kalman_update
from lio_cli.core.fuse.smoother import rts_smooth
from lio_cli.simulation.fusion_case import OdomNoise, simulate_case

EQUAL_TOL = 1e-9


def add(x, dx):
    x += dx


def sub(a, b):
    return a - b


def linear_case(seed: int = 3):
    """1-D constant velocity, irregular steps, position measured at some knots only."""
    rng = np.random.default_rng(seed)
    dts = rng.uniform(0.05, 0.3, 24)
    measured = rng.random(25) < 0.6
    measured[0] = True
    z = np.cumsum(np.concatenate([[0.0], dts])) * 1.5 + rng.normal(0, 0.2, 25)
    return dts, measured, z


def Fq(dt: float, q: float = 0.3):
    F = np.array([[1.0, dt], [0.0, 1.0]])
    Q = q * np.array([[dt**3 / 3, dt**2 / 2], [dt**2 / 2, dt]])
    return F, Q


def test_rts_equals_batch_least_squares():
    dts, measured, z = linear_case()
    m0, P0, R = np.array([0.0, 1.0]), np.diag([1.0, 0.25]), 0.04
    H = np.array([[1.0, 0.0]])
    log = KnotLog(for_smoother=True)
    x, P, Phi = m0.copy(), P0.copy(), np.eye(2)
    for k in range(25):
        if k > 0:
            F, Q = Fq(dts[k - 1])
            x, P, Phi = F @ x, F @ P @ F.T + Q, F
        log.open(k, x, P, Phi)
        if measured[k]:
            P, _ = kalman_update(x, P, np.array([z[k] - x[0]]), H, np.array([[R]]), add, None, "p")
        log.close(x, P)
    xs, Ps = rts_smooth(log.arrays(), add, sub)

    # batch: minimise prior + process + measurement terms over all 25 states at once
    n = 50
    A = np.zeros((n, n))
    b = np.zeros(n)
    P0i = np.linalg.inv(P0)
    A[0:2, 0:2] += P0i
    b[0:2] += P0i @ m0
    for k in range(1, 25):
        F, Q = Fq(dts[k - 1])
        Qi = np.linalg.inv(Q)
        J = np.zeros((2, n))
        J[:, 2 * k - 2:2 * k] = -F
        J[:, 2 * k:2 * k + 2] = np.eye(2)
        A += J.T @ Qi @ J
    for k in np.flatnonzero(measured):
        A[2 * k, 2 * k] += 1.0 / R
        b[2 * k] += z[k] / R
    mean = np.linalg.solve(A, b).reshape(25, 2)
    cov = np.linalg.inv(A)
    np.testing.assert_allclose(xs, mean, atol=EQUAL_TOL)
    for k in range(25):
        np.testing.assert_allclose(Ps[k], cov[2 * k:2 * k + 2, 2 * k:2 * k + 2], atol=EQUAL_TOL)


@pytest.mark.parametrize("kind", ["rts", "factor_graph"])
def test_smoother_beats_filter_between_scans_and_shrinks_covariance(kind, monkeypatch):
    from lio_cli.core.fuse import graph
    from lio_cli.evaluation import EvalOptions, Trajectory, evaluate

    if kind == "rts":  # the RTS pass, which --smooth keeps for filters without an accelerometer
        monkeypatch.setattr(graph, "applies", lambda prep: False)
    case = simulate_case("handheld", 12.0, seed=5, wheels=False, odom=OdomNoise())
    ref = Trajectory(case.truth_stamps_ns, case.truth_poses, "gt")
    filt = fuse(case.inputs, FuseOptions(estimator="ekf"))
    smooth = fuse(case.inputs, FuseOptions(estimator="ekf", smooth=True))
    assert smooth.info["smoother"]["kind"] == kind
    opts = EvalOptions(align="se3", delta=0.05, delta_unit="s", max_diff_ns=1_000_000)
    rpe_f = evaluate(ref, Trajectory(filt.stamps_ns, filt.poses, "f"), opts).stats["rpe"]["trans"]["rmse"]
    rpe_s = evaluate(ref, Trajectory(smooth.stamps_ns, smooth.poses, "s"), opts).stats["rpe"]["trans"]["rmse"]
    assert rpe_s < 0.3 * rpe_f, (rpe_s, rpe_f)
    tr_f = np.trace(filt.covariances[:, :3, :3], axis1=1, axis2=2)
    tr_s = np.trace(smooth.covariances[:, :3, :3], axis1=1, axis2=2)
    assert np.all(tr_s <= tr_f * (1 + 1e-9))
    if kind == "rts":
        assert np.median(tr_s / tr_f) < 0.8
    else:  # the graph writes the filter's pose covariance (an upper bound of its own)
        np.testing.assert_allclose(smooth.covariances, filt.covariances)
