"""The shared Kalman update and gate, on cases whose numbers can be checked by hand."""

from __future__ import annotations

import numpy as np
import pytest

from lio_cli.core.fuse.kalman import Anchor, Gate, KnotLog, chi2_thresholds, kalman_update, small_inv

TOL = 1e-12


def add(x: np.ndarray, dx: np.ndarray) -> None:
    x += dx


def test_constant_velocity_gain_by_hand():
    # state (p, v); after a predict of dt = 0.1 s from P0 = diag(0.04, 1): P = F P0 F^T
    dt = 0.1
    F = np.array([[1.0, dt], [0.0, 1.0]])
    P = F @ np.diag([0.04, 1.0]) @ F.T  # [[0.05, 0.1], [0.1, 1.0]]
    x = np.array([1.0, 2.0])
    z, var = 1.3, 0.05
    P_new, status = kalman_update(x, P, np.array([z - x[0]]), np.array([[1.0, 0.0]]), np.array([[var]]), add, None, "p")
    # by hand: S = 0.05 + 0.05 = 0.1, K = (0.05, 0.1) / 0.1 = (0.5, 1.0)
    assert status == "ok"
    np.testing.assert_allclose(x, [1.0 + 0.5 * 0.3, 2.0 + 1.0 * 0.3], atol=TOL)
    # P - K S K^T = [[0.05 - 0.025, 0.1 - 0.05], [0.1 - 0.05, 1.0 - 0.1]]
    np.testing.assert_allclose(P_new, [[0.025, 0.05], [0.05, 0.9]], atol=TOL)


def test_chi2_thresholds_match_tables():
    thr = chi2_thresholds(1e-4)
    # chi-square quantiles at 0.9999 (e.g. scipy.stats.chi2.ppf(0.9999, m))
    np.testing.assert_allclose(thr[1:4], [15.1367052, 18.4206807, 21.1075048], rtol=1e-6)
    assert np.all(np.isinf(chi2_thresholds(0.0)))


def test_gate_rejects_outliers_and_forces_after_a_streak_with_inflated_covariance():
    gate = Gate(1e-4, 2)
    P = np.diag([0.01, 1.0])
    H = np.array([[1.0, 0.0]])
    Rn = np.array([[0.01]])
    x = np.zeros(2)
    outcomes = []
    for _ in range(3):
        P_out, status = kalman_update(x, P, np.array([2.0]), H, Rn, add, gate, "p")
        outcomes.append(status)
    assert outcomes == ["outlier", "outlier", "reset"]
    # reset: d2 = 4 / 0.02 = 200 -> P[0,0] scaled by 200 -> K = 2 / 2.01, the state moves almost all the way
    np.testing.assert_allclose(x[0], 2.0 * 2.0 / 2.01, rtol=1e-12)
    # the second component is untouched by H, so it is neither inflated nor correlated
    np.testing.assert_allclose(P_out[1, 1], 1.0)
    # after the reset the streak is over: a consistent measurement passes again
    assert kalman_update(x, P_out, np.array([0.0]), H, Rn, add, gate, "p")[1] == "ok"


def test_gate_without_reset_keeps_rejecting():
    gate = Gate(1e-4, 1)
    assert [gate.check("w", 100.0, 1, allow_reset=False)[0] for _ in range(5)] == [False] * 5


@pytest.mark.parametrize("m", [1, 2, 3, 4])
def test_small_inverse_matches_numpy(m):
    rng = np.random.default_rng(m)
    A = rng.normal(size=(m, m))
    S = A @ A.T + np.eye(m)
    np.testing.assert_allclose(small_inv(S), np.linalg.inv(S), rtol=1e-12, atol=1e-12)


def test_knot_log_keeps_only_outputs_without_smoother():
    log = KnotLog(for_smoother=False, keep=np.array([1]))
    x, P = np.zeros(2), np.array([[1.0, 0.5], [0.5, 2.0]])
    log.open(1, x, P, None)
    log.close(x, P)  # an update-only knot: dropped
    log.open(2, x, P, None)
    log.mark_output()
    log.close(x + 1, P)
    out = log.arrays()
    np.testing.assert_array_equal(out["t_ns"], [2])
    np.testing.assert_allclose(out["x_filt"], [[1.0, 1.0]])
    np.testing.assert_allclose(out["P_filt"], [[[2.0]]])  # only the kept block


def test_knot_log_takes_states_as_lists_of_floats_alike():
    # the 3D filter keeps its state as a list of floats; the smoother reads the same arrays either way
    rng = np.random.default_rng(3)
    states = rng.normal(size=(4, 2, 5))  # per knot: predicted, filtered
    P = np.eye(5)
    out = []
    for as_list in (False, True):
        log = KnotLog(for_smoother=True)
        for k, (xp, xf) in enumerate(states):
            log.open(k, xp.tolist() if as_list else xp.copy(), P, None)
            log.mark_output()
            log.close(xf.tolist() if as_list else xf.copy(), P)
        out.append(log.arrays())
    for key in ("x_pred", "x_filt"):
        assert out[1][key].dtype == np.float64 and np.array_equal(out[1][key], out[0][key])
    np.testing.assert_array_equal(out[1]["x_filt"], states[:, 1])


def test_a_reset_inflates_only_the_reset_states_when_given():
    """A measurement of state 1 whose H also reaches state 0 through a linearisation lever (a body velocity on
    the attitude): with ``reset_states`` the reset inflates state 1 only, and state 0 keeps its variance."""
    P = np.array([[0.01, 0.005], [0.005, 0.01]])
    H, Rn, r = np.array([[0.5, 1.0]]), np.array([[0.01]]), np.array([3.0])
    wide = kalman_update(np.zeros(2), P, r, H, Rn, add, Gate(1e-4, 0), "v")
    narrow = kalman_update(np.zeros(2), P, r, H, Rn, add, Gate(1e-4, 0), "v", reset_states=[1])
    assert wide[1] == narrow[1] == "reset"
    assert wide[0][0, 0] > 10 * P[0, 0]  # H's lever column inflated with the rest
    assert narrow[0][0, 0] <= P[0, 0]



def test_an_accepted_pose_source_defers_the_reset_for_two_of_its_periods():
    a = Anchor({"odom": 100, "gps": 1000}, t0_ns=0)
    assert a.allows_reset(0)
    a.accepted("wheel", 10, "ok")  # not a pose source
    a.accepted("odom", 10, "outlier")  # rejected: no anchor
    assert a.allows_reset(11)
    a.accepted("odom", 10, "ok")
    assert not a.allows_reset(210) and a.allows_reset(211)
    a.accepted("gps", 20, "ok")
    a.accepted("odom", 30, "ok")  # a shorter window does not cut a longer one
    assert not a.allows_reset(2020) and a.allows_reset(2021)
    gate = Gate(1e-4, 2)  # the deferred streak: forced in at the first rejection after the anchor lapses
    assert [gate.check("v", 1e6, 1, allow_reset=a.allows_reset(t)) for t in (100, 200, 300, 2100)] == [
        (False, False)] * 3 + [(True, True)]
