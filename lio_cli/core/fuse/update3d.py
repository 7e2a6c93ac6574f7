"""The Kalman update of the 3D filter's hot loop (``kalman.kalman_update`` in place on one covariance buffer),
for measurements whose model already has ``P H^T`` and ``S`` at hand: the 3-row ones (the IMU's orientation,
the wheels' body velocity) with the inverse and the gate's distance unrolled on Python floats, the others
through ``inverse_small``. The tests compare it with ``kalman_update``: equal up to rounding (gate resets,
with or without ``reset_states``, included).
"""

from __future__ import annotations

import math

import numpy as np

from .kalman import Gate, reset_scale


def inverse_small(S: list[list[float]]) -> list[list[float]] | None:
    """``kalman.small_inv`` on nested lists (m <= 2), None when singular; numpy beyond (``Updater`` inverts
    the usual 3x3 itself, unrolled)."""
    m = len(S)
    if m == 1:
        s = S[0][0]
        return None if s == 0.0 else [[1.0 / s]]
    if m == 2:
        (a, b), (c, d) = S
        det = a * d - b * c
        if det == 0.0 or not math.isfinite(det):
            return None
        return [[d / det, -b / det], [-c / det, a / det]]
    try:
        return np.linalg.inv(np.array(S)).tolist()
    except np.linalg.LinAlgError:
        return None


class Updater:
    """``kalman.kalman_update`` in place on one covariance buffer, given what the measurement model already
    has at hand: ``PHt = P H^T`` (may be a view of P) and ``S = H P H^T + Rn`` as nested lists. ``H`` and
    ``Rn`` are only read on a gate reset, which inflates the states ``reset_states`` (an index or slice of the
    error state; default: every state H touches, see ``kalman.kalman_update``)."""

    def __init__(self, gate: Gate | None, inject):
        self.gate, self.inject = gate, inject
        self.hold: list[int] | None = None  # error states a "consider" update leaves alone (set per call)
        self._Si = [np.empty((m, m)) for m in range(4)]  # S^-1 of 1-3 rows written here, not a new array
        self._Si3 = self._Si[3].reshape(-1)  # the 3x3 one's flat view (a flat list goes in faster)

    def __call__(self, x: np.ndarray, P: np.ndarray, r: list[float], PHt: np.ndarray, S: list[list[float]],
                 H: np.ndarray, Rn, kind: str, allow_reset: bool = True, reset_states=None) -> str:
        m = len(r)
        if m == 3:  # the usual measurement (orientation, body velocity): inverse_small and r^T Si r unrolled
            (a, b, c), (d, e, f), (g, h, i) = S
            A, B, C = e * i - f * h, f * g - d * i, d * h - e * g
            det = a * A + b * B + c * C
            if det == 0.0 or not math.isfinite(det):
                return "outlier"
            Si = [A / det, (c * h - b * i) / det, (b * f - c * e) / det,
                  B / det, (a * i - c * g) / det, (c * d - a * f) / det,
                  C / det, (b * g - a * h) / det, (a * e - b * d) / det]
            if self.gate is None:
                return self._apply(x, P, r, PHt, Si, 3, "ok")
            a0, a1, a2, b0, b1, b2, c0, c1, c2 = Si
            x0, x1, x2 = r
            d2 = (x0 * a0 + x1 * b0 + x2 * c0) * x0 + (x0 * a1 + x1 * b1 + x2 * c1) * x1 \
                + (x0 * a2 + x1 * b2 + x2 * c2) * x2
            ok, reset = self.gate.check(kind, d2, 3, allow_reset)
            if not ok:
                return "outlier"
            if not reset:
                return self._apply(x, P, r, PHt, Si, 3, "ok")
            return self._reset(x, P, r, H, Rn, d2, reset_states)
        Si = inverse_small(S)
        if Si is None:
            return "outlier"
        if self.gate is None:
            return self._apply(x, P, r, PHt, Si, m, "ok")
        d2 = 0.0
        for j in range(m):
            tj = 0.0
            for k in range(m):
                tj += r[k] * Si[k][j]
            d2 += tj * r[j]
        ok, reset = self.gate.check(kind, d2, m, allow_reset)
        if not ok:
            return "outlier"
        if not reset:
            return self._apply(x, P, r, PHt, Si, m, "ok")
        return self._reset(x, P, r, H, Rn, d2, reset_states)

    def _reset(self, x, P: np.ndarray, r: list[float], H: np.ndarray, Rn, d2: float, reset_states=None) -> str:
        """As kalman_update on a gate reset: inflate the covariance of ``reset_states`` (default: the states
        H touches) until the innovation is typical, then update."""
        m = len(r)
        Rn = Rn if isinstance(Rn, np.ndarray) else np.diag(Rn)
        scale = reset_scale(H, d2, reset_states)
        P *= np.outer(scale, scale)
        PHt = P @ H.T
        return self._apply(x, P, r, PHt, np.linalg.inv(H @ PHt + Rn), m, "reset")

    def _apply(self, x, P: np.ndarray, r: list[float], PHt: np.ndarray, Si, m: int, status: str) -> str:
        """x [+]= K r and P -= K PHt^T with K = PHt Si (``Si`` as floats: row-major for 3x3, nested below)."""
        # ndarray.dot, not @: half the per-call overhead on matrices this small
        if m < 4:
            Sa = self._Si[m]
            if m == 3 and not isinstance(Si, np.ndarray):
                self._Si3[:] = Si
            else:
                Sa[...] = Si
        else:
            Sa = np.asarray(Si)
        K = PHt.dot(Sa)
        if self.hold:  # Schmidt ("consider") update: these states keep their value, P stays consistent
            K[self.hold] = 0.0
            A = K.dot(PHt.T)
            P += K.dot(np.linalg.inv(Sa)).dot(K.T) - A - A.T
            self.inject(x, K.dot(r))
            return status
        self.inject(x, K.dot(r))
        P -= K.dot(PHt.T)
        return status
