"""The offset cost's pieces: closed-form residuals against explicit fits, the noise gauge, the interpolation."""

from __future__ import annotations

import numpy as np
import pytest

from lio_cli.evaluation import Trajectory
from lio_cli.evaluation.alignment import posyaw, umeyama
from lio_cli.evaluation.offset_cost import (
    OffsetCost,
    best_rotation,
    hermite_coefficients,
    noise_level_m,
    position_msq,
    rotation_msq,
)
from lio_cli.geometry import so3_exp

CLOSED_FORM_TOL = 1e-10


@pytest.mark.parametrize("mode", ["none", "se3", "sim3", "posyaw"])
def test_position_residual_equals_the_applied_fit(mode):
    rng = np.random.default_rng(1)
    src = rng.normal(0, 5, (200, 3))
    dst = 1.1 * src @ so3_exp(np.array([0.1, 0.2, 0.9])).T + [1.0, 2.0, 3.0] + rng.normal(0, 0.2, (200, 3))
    if mode == "none":
        res = dst - src
    elif mode == "posyaw":
        R, t = posyaw(src, dst)
        res = dst - (src @ R.T + t)
    else:
        R, t, s = umeyama(src, dst, with_scale=mode == "sim3")
        res = dst - (s * src @ R.T + t)
    assert position_msq(src, dst, mode) == pytest.approx(np.mean(np.sum(res**2, axis=1)), rel=CLOSED_FORM_TOL)


@pytest.mark.parametrize("mode", ["none", "se3", "posyaw"])
def test_rotation_residual_equals_the_best_constant_rotation(mode):
    rng = np.random.default_rng(2)
    R_est = so3_exp(rng.normal(0, 1.0, (100, 3)))
    Q_true = so3_exp(np.array([0.0, 0.0, 0.6]) if mode == "posyaw" else np.array([0.3, -0.2, 0.6]))
    R_ref = np.einsum("ij,njk->nik", Q_true, R_est) @ so3_exp(rng.normal(0, 0.01, (100, 3)))
    M = np.einsum("nij,nkj->ik", R_ref, R_est)
    Q = best_rotation(M, mode)
    explicit = np.mean(np.sum((R_ref - np.einsum("ij,njk->nik", Q, R_est)) ** 2, axis=(1, 2)))
    assert rotation_msq(M, 100, mode) == pytest.approx(explicit, rel=CLOSED_FORM_TOL)
    if mode != "none":
        np.testing.assert_allclose(Q, Q_true, atol=0.01)  # the noise is 0.01 rad per pose


def test_noise_gauge_sees_white_noise_not_smooth_motion():
    rng = np.random.default_rng(3)
    t = np.sort(rng.uniform(0, 100, 4000))  # irregular stamps
    smooth = np.stack([20 * np.sin(0.1 * t), 5 * t, np.cos(0.3 * t)], axis=1)
    assert noise_level_m(t, smooth) < 1e-4
    assert noise_level_m(t, smooth + rng.normal(0, 0.02, smooth.shape)) == pytest.approx(0.02, rel=0.1)
    assert np.isnan(noise_level_m(t[:4], smooth[:4]))


def test_hermite_hits_the_samples_and_reproduces_a_line():
    t = np.array([0.0, 0.5, 1.5, 2.0, 3.5])  # uneven spacing
    p = np.stack([t**2, 3 * t - 1, np.ones_like(t)], axis=1)
    c = hermite_coefficients(t, p)
    np.testing.assert_allclose(c[:, 0], p[:-1])  # u = 0
    np.testing.assert_allclose(c.sum(axis=1), p[1:], atol=1e-12)  # u = 1
    u = 0.3  # between samples a straight and a constant axis come out exactly
    q = t[:-1] + u * np.diff(t)
    val = c[:, 0] + u * (c[:, 1] + u * (c[:, 2] + u * c[:, 3]))
    np.testing.assert_allclose(val[:, 1:], np.stack([3 * q - 1, np.ones_like(q)], axis=1), atol=1e-12)


def test_the_smoother_side_is_interpolated():
    rng = np.random.default_rng(4)
    t = np.arange(0, 30, 0.1)
    clean = np.repeat(np.eye(4)[None], len(t), axis=0)
    clean[:, :3, 3] = np.stack([np.sin(t), t, 0 * t], axis=1)
    noisy = clean.copy()
    noisy[:, :3, 3] += rng.normal(0, 0.05, (len(t), 3))
    ns = (t * 1e9).astype(np.int64)
    # equal counts: density cannot decide; the noisy side is the one queried
    assert OffsetCost(Trajectory(ns, clean, "ref"), Trajectory(ns, noisy, "est"), "se3", False).query_est
    assert not OffsetCost(Trajectory(ns, noisy, "ref"), Trajectory(ns, clean, "est"), "se3", False).query_est
