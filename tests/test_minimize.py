"""Brent's bounded minimisation against known minima and against scipy's implementation of the same method."""

from __future__ import annotations

import math

import pytest
from scipy.optimize import minimize_scalar

from lio_cli.minimize import minimize_bounded

CASES = [
    (lambda x: (x - 0.3) ** 2, -1.0, 2.0, 0.3),
    (math.cos, 0.0, 6.0, math.pi),
    (lambda x: abs(x - 0.123456), -1.0, 1.0, 0.123456),  # a kink: golden-section steps only
    (lambda x: x, 0.0, 1.0, 0.0),  # minimum at an end
    (lambda x: -x, 0.0, 1.0, 1.0),
    (lambda x: (x - 5.0) ** 4, 0.0, 10.0, 5.0),  # flat bottom
]


@pytest.mark.parametrize("f, lo, hi, truth", CASES)
def test_finds_the_minimum_to_the_tolerance_and_as_scipy_does(f, lo, hi, truth):
    x, fx = minimize_bounded(f, lo, hi, xatol=1e-6)
    assert abs(x - truth) < (2e-2 if truth == 5.0 else 1e-5)  # x^4 is too flat to pin x beyond ~fx^(1/4)
    assert fx == f(x)
    ref = minimize_scalar(f, bounds=(lo, hi), method="bounded", options={"xatol": 1e-6})
    assert x == pytest.approx(ref.x, abs=1e-9) and fx == pytest.approx(ref.fun, abs=1e-12)


def test_a_local_minimum_inside_the_bracket():
    x, _ = minimize_bounded(lambda v: math.sin(3 * v) + 0.3 * v * v, -3.0, 3.0, xatol=1e-8)
    assert abs(3 * math.cos(3 * x) + 0.6 * x) < 1e-6  # a stationary point
    assert -3.0 < x < 3.0


def test_an_empty_interval_is_refused():
    with pytest.raises(ValueError, match=r"empty interval \[1.0, 1.0\]"):
        minimize_bounded(lambda v: v, 1.0, 1.0)
