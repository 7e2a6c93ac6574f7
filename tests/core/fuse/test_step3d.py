"""The hot-loop kernels of the 3D filter (step3d) against the reference model (state3d, kalman): the same
numbers up to rounding."""

from __future__ import annotations

import numpy as np
import pytest

from lio_cli.core.fuse import measure3d as m3
from lio_cli.core.fuse import step3d
from lio_cli.core.fuse.kalman import Gate, kalman_update
from lio_cli.core.fuse.state3d import DV, Layout, boxplus, ins_step, new_state
from lio_cli.core.fuse.update3d import Updater
from lio_cli.geometry import so3_exp

TOL = 1e-12


def _state(rng, L):
    x = new_state(so3_exp(rng.normal(size=3)), rng.normal(size=3), rng.normal(size=3), 0.05 * rng.normal(size=3),
                  0.1 * rng.normal(size=3))
    if L.clone:
        x[21:30] = so3_exp(rng.normal(size=3)).reshape(9)
        x[30:33] = rng.normal(size=3)
    return x


def test_ins_predictor_equals_ins_step():
    L, g = Layout("ins", clone=True), np.array([0.0, 0.0, -9.81])
    rng = np.random.default_rng(5)
    pred = step3d.InsPredictor(L, g)
    for _ in range(20):
        x = _state(rng, L)
        w, f, dt = rng.normal(size=3), rng.normal(size=3) + [0, 0, 9.8], rng.uniform(1e-4, 0.05)
        xa, xb = x.copy(), x.tolist()  # the filter's state is a list of floats
        Fa = ins_step(xa, dt, w, f, L, g)
        Fb = pred(xb, dt, tuple(w.tolist()), tuple(f.tolist()))
        np.testing.assert_allclose(Fb, Fa, rtol=0, atol=TOL)
        np.testing.assert_allclose(np.array(xb), xa, rtol=0, atol=TOL)


def test_boxplus_equals_the_reference():
    for clone in (False, True):
        L = Layout("ins", clone)
        rng = np.random.default_rng(6)
        x = _state(rng, L)
        d = 0.3 * rng.normal(size=L.n)
        xa, xb, xc = x.copy(), x.copy(), x.tolist()
        boxplus(xa, d, L)
        step3d.boxplus(xb, d, L)
        step3d.inject(xc, d, L)  # the filter's state list
        np.testing.assert_allclose(xb, xa, rtol=0, atol=TOL)
        assert len(xc) == len(x) and xc == xb.tolist()


def test_updater_equals_kalman_update_and_gates_alike():
    L = Layout("ins", clone=False)
    rng = np.random.default_rng(7)
    inject = lambda x, dx: boxplus(x, dx, L)  # noqa: E731
    for m, scale in ((1, 0.1), (2, 0.1), (3, 0.1), (6, 0.1), (3, 50.0)):
        A = rng.normal(size=(L.n, L.n))
        P = A @ A.T * 0.01 + np.eye(L.n) * 1e-3
        H, Rn, r = rng.normal(size=(m, L.n)), np.diag(rng.uniform(0.01, 0.1, m)), scale * rng.normal(size=m)
        x = _state(rng, L)
        xa, xb, Pb = x.copy(), x.copy(), P.copy()
        Pa, sa = kalman_update(xa, P.copy(), r, H, Rn, inject, Gate(0.999, 2), "k")
        PHt = Pb @ H.T
        sb = Updater(Gate(0.999, 2), inject)(xb, Pb, r.tolist(), PHt, (H @ PHt + Rn).tolist(), H, Rn, "k")
        assert sa == sb
        np.testing.assert_allclose(Pb, Pa, rtol=1e-10, atol=1e-15)
        np.testing.assert_allclose(xb, xa, rtol=1e-10, atol=1e-13)
        # a reset of the velocity only (the wheels' body velocity): the same too
        xa, xb, Pb = x.copy(), x.copy(), P.copy()
        Pa, sa = kalman_update(xa, P.copy(), r, H, Rn, inject, Gate(0.999, 0), "k", reset_states=DV)
        PHt = Pb @ H.T
        sb = Updater(Gate(0.999, 0), inject)(xb, Pb, r.tolist(), PHt, (H @ PHt + Rn).tolist(), H, Rn, "k",
                                             reset_states=DV)
        assert sa == sb
        np.testing.assert_allclose(Pb, Pa, rtol=1e-10, atol=1e-15)
        np.testing.assert_allclose(xb, xa, rtol=1e-10, atol=1e-13)


def test_measurement_kernels_equal_the_measurement_models():
    # measure3d's models are the ones whose Jacobians test_measure3d checks by finite differences
    L = Layout("ins", clone=False)
    rng = np.random.default_rng(8)
    H3 = np.zeros((3, L.n))  # the filter's H of three rows, rewritten in place message after message
    for comps in ([0], [0, 2], [0, 1, 2], [1, 2], (0, 1, 2), (1, 2, 0), (0, 1, 2)):  # tuples: the filter's rows
        x = _state(rng, L)
        z, var = rng.normal(size=len(comps)), rng.uniform(0.01, 0.1, len(comps))
        r_ref, H_ref, Rn_ref = m3.body_velocity(x, z, list(comps), var, L)
        H = H3 if len(comps) == 3 else np.zeros((len(comps), L.n))
        r = step3d.body_velocity(x.tolist(), z.tolist(), comps, H)
        np.testing.assert_allclose(r, r_ref, rtol=0, atol=TOL)
        np.testing.assert_allclose(H, H_ref, rtol=0, atol=TOL)
    for _ in range(5):
        x = _state(rng, L)
        R_meas, A = so3_exp(rng.normal(size=3)), rng.normal(size=(3, 3))
        cov = A @ A.T
        r_ref, H_ref, Rn_ref = m3.orientation(x, R_meas, cov, L)
        r, Rn = step3d.orientation(x.tolist(), R_meas.ravel().tolist(), cov)
        np.testing.assert_allclose(r, r_ref, rtol=0, atol=TOL)
        np.testing.assert_allclose(Rn, Rn_ref, rtol=0, atol=TOL * 10)
        iso = np.eye(3) * rng.uniform(1e-3, 1e-1)  # a usual driver's covariance: no rotation changes it
        assert step3d.isotropic_variances(np.stack([cov, iso, iso + 1e-9 * np.eye(3)[::-1]])) == [None, iso[0, 0], None]
        r_ref, _, Rn_ref = m3.orientation(x, R_meas, iso, L)
        r, Rn = step3d.orientation(x.tolist(), R_meas.ravel().tolist(), iso, isotropic=True)
        np.testing.assert_allclose(r, r_ref, rtol=0, atol=TOL)
        np.testing.assert_allclose(Rn, Rn_ref, rtol=1e-14, atol=1e-15 * iso[0, 0])  # R^T R = I to rounding
        assert (H_ref[:, 0:3] == np.eye(3)).all() and not H_ref[:, 3:].any()  # the selection _orientation assumes


def test_wheel_rows_of_whole_messages_equal_the_per_message_rule():
    rng = np.random.default_rng(9)
    vel, var = rng.normal(size=(40, 3)), rng.uniform(0.01, 0.1, (40, 3))
    vel[::3, 1] = np.nan  # a lateral speed missing now and then
    vel[::7, 0] = np.nan  # and the forward speed
    for use in ({"velocity"}, {"speed"}, {"velocity", "speed"}):
        rows = step3d.wheel_velocity_rows(vel, var, use, 0.2, 0.5)
        for row, v, vv in zip(rows, vel.tolist(), var.tolist()):
            nh = 0.04 + (0.5 * v[0]) ** 2 if np.isfinite(v[0]) else 0.04  # grows with the forward speed
            want = step3d._wheel_row(v, vv, use, nh)
            assert (row is None) == (want is None)
            if row is not None:
                assert tuple(row[0]) == want[0] and list(row[1]) == want[1]
                assert list(row[2]) == pytest.approx(want[2], rel=1e-15)
    rows = step3d.wheel_velocity_rows(vel, var, {"speed"}, 0.2)
    assert rows[1] == ((0, 1, 2), [vel[1, 0], 0.0, 0.0], [var[1, 0], pytest.approx(0.04), pytest.approx(0.04)])
    assert rows[0] is None  # no forward speed: nothing to say with speed alone


def test_interval_midpoints_equal_the_interpolation_of_the_filter():
    rng = np.random.default_rng(10)
    st = 1_300_000_000_000_000_000 + np.cumsum(rng.integers(4_000_000, 6_000_000, 30))  # epoch ns: float rounding
    w, f = rng.normal(size=(30, 3)), rng.normal(size=(30, 3))
    mid_w, mid_f = step3d.interval_midpoints(st, w, f)
    for i in range(29):
        a, b = int(st[i]), int(st[i + 1])
        t = (0.5 * (a + b) - a) / (b - a)
        assert mid_w[i] == [w[i, k] + t * (w[i + 1, k] - w[i, k]) for k in range(3)]
        assert mid_f[i] == [f[i, k] + t * (f[i + 1, k] - f[i, k]) for k in range(3)]
