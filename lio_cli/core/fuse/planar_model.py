"""The planar EKF's model: state ``[x, y, theta, v, omega, b_omega]`` (indices ``X`` .. ``BW``), the lecture's
step (``predict``), its variants across a gap of the gyro (``predict_turn_decay``) or of every motion source
(``predict_gap``), an odometry increment's residual against a clone (``delta_residual``) and the turn rate's
random walk the gyro shows (``turn_rate_walk``).
"""

from __future__ import annotations

import math

import numpy as np

from ...geometry import yaw_of
from ..robust import white_variance
from .sanitize import median_period_ns
from .state3d import GAP_TAU_S

X, Y, TH, V, W, BW = range(6)
TURN_WINDOW_S = 0.1  # the gyro's means over this long show how fast the turn rate changes
MIN_TURN_WALK = 1e-3  # rad/s^2/sqrt(Hz): never less (a log that never turns)


def wrap(a: float) -> float:
    return (a + math.pi) % (2.0 * math.pi) - math.pi


def turn_rate_walk(t_ns: np.ndarray, wz: np.ndarray) -> float:
    """The turn rate's random-walk density (rad/s^2/sqrt(Hz)) the gyro shows: the mean square change of its means
    over ``TURN_WINDOW_S`` from one window to the next, less what its white noise (from its second differences)
    puts there, is 2/3 of the density squared times the window for a random walk. The configured motion model's
    (up to 1 rad/s^2/sqrt(Hz)) let the turn rate jump between two wheel messages, so the gyro's noise, not the
    wheels' rate, set the heading there."""
    period = median_period_ns(t_ns) * 1e-9 if len(t_ns) > 1 else 0.0
    n = int(round(TURN_WINDOW_S / period)) if period > 0 else 0
    m = len(wz) // n if n else 0
    if m < 3:
        return math.inf
    means = wz[:m * n].reshape(m, n).mean(axis=1)
    white = white_variance(wz)
    change = float(np.mean(np.diff(means) ** 2)) - 2.0 * white / n
    return math.sqrt(max(1.5 * change / (n * period), MIN_TURN_WALK**2))


def predict(x: np.ndarray, dt: float, n: int) -> np.ndarray:
    """The lecture's step ``x += v cos(theta) dt``, ``y += v sin(theta) dt``, ``theta += omega dt`` in
    place, the heading taken at the step's middle (``theta + omega dt / 2``: exact to second order on an
    arc); returns its Jacobian F (n x n)."""
    v, w = x[V], x[W]
    th_mid = x[TH] + 0.5 * w * dt
    c, s = math.cos(th_mid), math.sin(th_mid)
    F = np.eye(n)
    F[X, TH], F[X, V], F[X, W] = -v * s * dt, c * dt, -0.5 * v * s * dt * dt
    F[Y, TH], F[Y, V], F[Y, W] = v * c * dt, s * dt, 0.5 * v * c * dt * dt
    F[TH, W] = dt
    x[X] += v * c * dt
    x[Y] += v * s * dt
    x[TH] = wrap(x[TH] + w * dt)
    return F


def predict_turn_decay(x: np.ndarray, dt: float, n: int, tau_s: float = GAP_TAU_S) -> np.ndarray:
    """``predict``, then the turn rate decays with ``exp(-dt/tau)`` (no gyro holds it); returns F."""
    F = predict(x, dt, n)
    e = math.exp(-dt / tau_s)
    x[W] *= e
    F[W, :] *= e
    return F


def predict_gap(x: np.ndarray, dt: float, n: int, tau_s: float = GAP_TAU_S) -> np.ndarray:
    """Across a gap of every motion source: ``v`` and ``omega`` decay with ``e = exp(-dt/tau)``, the pose
    moves ``v tau (1 - e)`` along the heading and turns ``omega tau (1 - e)``; returns F."""
    e = math.exp(-dt / tau_s)
    k = tau_s * (1.0 - e)
    c, s = math.cos(x[TH]), math.sin(x[TH])
    v = x[V]
    F = np.eye(n)
    F[X, TH], F[X, V] = -v * s * k, c * k
    F[Y, TH], F[Y, V] = v * c * k, s * k
    F[TH, W] = k
    F[V, V] = F[W, W] = e
    x[X] += v * c * k
    x[Y] += v * s * k
    x[TH] = wrap(x[TH] + x[W] * k)
    x[V] *= e
    x[W] *= e
    return F


def delta_residual(x: np.ndarray, D: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Residual and Jacobian of a measured planar increment ``D`` (4x4) from the clone ``x[6:9]`` to the
    current pose: ``h = (R(theta_c)^T (p - p_c), theta - theta_c)``."""
    c, s = math.cos(x[8]), math.sin(x[8])
    dx, dy = x[X] - x[6], x[Y] - x[7]
    h = np.array([c * dx + s * dy, -s * dx + c * dy, wrap(x[TH] - x[8])])
    H = np.zeros((3, len(x)))
    H[0:2, 0:2] = [[c, s], [-s, c]]
    H[0:2, 6:8] = [[-c, -s], [s, -c]]
    H[0, 8], H[1, 8] = -s * dx + c * dy, -c * dx - s * dy
    H[2, TH], H[2, 8] = 1.0, -1.0
    r = np.array([D[0, 3] - h[0], D[1, 3] - h[1], wrap(float(yaw_of(D[:3, :3])) - h[2])])
    return r, H
