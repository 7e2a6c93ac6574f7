"""The Kalman update shared by the 3D and planar filters, the chi-square gate, and the record of filter
states ("knots") that the output and the RTS smoother read.

A knot is an instant where the filter updated or an output was asked. Between two knots there are only
predictions, so the record holds, per knot: the predicted state and covariance (before the updates at
that instant), the filtered ones (after), and the transition ``Phi`` of the error state from the previous
knot. That is exactly what a Rauch-Tung-Striebel pass needs.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from itertools import chain

import numpy as np
from scipy.special import gammaincinv

from .sanitize import median_period_ns


def chi2_thresholds(probability: float, max_dim: int = 8) -> np.ndarray:
    """``thr[m]``: the chi-square quantile of ``1 - probability`` with m degrees of freedom (inf: no gate)."""
    thr = np.full(max_dim + 1, np.inf)
    if probability > 0.0:
        for m in range(1, max_dim + 1):
            thr[m] = 2.0 * gammaincinv(0.5 * m, 1.0 - probability)
    return thr


class Gate:
    """Chi-square gate with a reset: after ``max_rejects`` rejections in a row of one measurement kind the
    next one passes (the filter, not the sensor, is then assumed to be off)."""

    def __init__(self, probability: float, max_rejects: int):
        self._thr = chi2_thresholds(probability).tolist()  # Python floats: checked once per update in the loop
        self._last = len(self._thr) - 1
        self.max_rejects = max_rejects
        self.streak: dict[str, int] = {}

    def check(self, kind: str, d2: float, m: int, allow_reset: bool = True) -> tuple[bool, bool]:
        """(accept, was_reset). ``allow_reset=False`` for measurements that disagree with a sensor rather
        than with the state (a wheel yaw rate against the gyro): those are never forced in."""
        if not math.isfinite(d2):
            return False, False
        if d2 <= self._thr[m if m < self._last else self._last]:
            self.streak[kind] = 0
            return True, False
        n = self.streak.get(kind, 0) + 1
        if n > self.max_rejects and allow_reset:
            self.streak[kind] = 0
            return True, True
        self.streak[kind] = n
        return False, False


GPS_HOLD_S = 10.0  # GPS anchors the filter this long after an accepted fix against odometry resets


class Anchor:
    """Whether a pose source (odometry poses or increments, GPS) is being accepted: an update of one that
    passed the gate at t anchors the filter until t + twice that source's median period. While anchored, a
    streak of rejected wheel speeds is the wheels disagreeing (a slip), not the filter being off: their gate
    reset is deferred (the streak goes on, and the first rejection after the anchor lapses is forced in)."""

    def __init__(self, periods_ns: dict[str, int], t0_ns: int):
        self.window = {src: 2 * p for src, p in periods_ns.items() if p > 0}
        self.until = t0_ns - 1

    @classmethod
    def of(cls, prep) -> Anchor:
        """The pose sources of a ``timeline.Prepared``."""
        periods = {src: median_period_ns(s.stamps_ns) for src, s in (("odom", prep.odom), ("gps", prep.gps))
                   if s is not None}  # 0 for a single message: no window
        return cls(periods, prep.t0_ns)

    @classmethod
    def of_gps(cls, prep) -> Anchor:
        """GPS alone, for ``GPS_HOLD_S`` after each accepted fix (an odometry streak is not reset then: a GPS
        dropout of a few seconds is bridged, not taken as the filter being off)."""
        g = prep.gps
        a = cls({}, prep.t0_ns)
        if g is not None:
            a.window = {"gps": max(2 * median_period_ns(g.stamps_ns), int(GPS_HOLD_S * 1e9))}
        return a

    def accepted(self, source: str, t_ns: int, status: str) -> None:
        if status == "ok" and source in self.window:
            self.until = max(self.until, t_ns + self.window[source])

    def allows_reset(self, t_ns: int) -> bool:
        return t_ns > self.until


def reset_scale(H: np.ndarray, d2: float, reset_states=None) -> np.ndarray:
    """Per-state standard-deviation factors of a gate reset: sqrt(d2 / m), at least 1, on ``reset_states``
    (default: every state H touches), 1 elsewhere (``P * outer(scale, scale)`` stays positive definite)."""
    scale = np.ones(H.shape[1])
    scale[np.any(H != 0.0, axis=0) if reset_states is None else reset_states] = np.sqrt(max(1.0, d2 / len(H)))
    return scale


def small_inv(S: np.ndarray) -> np.ndarray:
    """Inverse of a small matrix: closed form up to 3x3 (numpy's per-call overhead dominates a filter step
    there), numpy beyond. Raises LinAlgError when singular."""
    m = len(S)
    if m == 1:
        if S[0, 0] == 0.0:
            raise np.linalg.LinAlgError("singular")
        return np.array([[1.0 / S[0, 0]]])
    if m == 2:
        a, b, c, d = S.ravel().tolist()
        det = a * d - b * c
        if det == 0.0 or not np.isfinite(det):
            raise np.linalg.LinAlgError("singular")
        return np.array([[d, -b], [-c, a]]) / det
    if m == 3:
        a, b, c, d, e, f, g, h, i = S.ravel().tolist()
        A, B, C = e * i - f * h, f * g - d * i, d * h - e * g
        det = a * A + b * B + c * C
        if det == 0.0 or not np.isfinite(det):
            raise np.linalg.LinAlgError("singular")
        return np.array([[A, c * h - b * i, b * f - c * e],
                         [B, a * i - c * g, c * d - a * f],
                         [C, b * g - a * h, a * e - b * d]]) / det
    return np.linalg.inv(S)


def kalman_update(x: np.ndarray, P: np.ndarray, r: np.ndarray, H: np.ndarray, Rn: np.ndarray,
                  inject: Callable[[np.ndarray, np.ndarray], None], gate: Gate | None, kind: str,
                  allow_reset: bool = True, reset_states=None) -> tuple[np.ndarray, str]:
    """Update ``x`` (via ``inject(x, dx)``) and return the new P and ``"ok"``, ``"reset"`` or ``"outlier"``
    (then P is returned unchanged and x untouched).

    On a gate reset the filter was overconfident: the covariance of the states the measurement touches is
    scaled up (``D P D`` with D = sqrt(d2/m) on those states, which keeps P positive definite) until the
    innovation is typical, so the reset measurement actually pulls the state back. ``reset_states`` (an index
    or slice of the error state) narrows that to the states the measurement is evidence about, where H also
    touches others only through the linearisation (a body velocity's ``[v_b]x`` on the attitude: inflating the
    attitude lets a speed disagreement turn the heading).
    """
    PHt = P @ H.T
    S = H @ PHt + Rn
    try:
        Sinv = small_inv(S)
    except np.linalg.LinAlgError:
        return P, "outlier"
    status = "ok"
    if gate is not None:
        d2 = float(r @ Sinv @ r)
        ok, reset = gate.check(kind, d2, len(r), allow_reset)
        if not ok:
            return P, "outlier"
        if reset:
            status = "reset"
            scale = reset_scale(H, d2, reset_states)
            P = P * np.outer(scale, scale)
            PHt = P @ H.T
            Sinv = np.linalg.inv(H @ PHt + Rn)
    K = PHt @ Sinv
    inject(x, K @ r)
    return P - K @ PHt.T, status  # symmetric up to rounding; callers symmetrise once per time step


def consider_update(x, P: np.ndarray, r: np.ndarray, H: np.ndarray, Rn: np.ndarray,
                    inject: Callable[[np.ndarray, np.ndarray], None], keep: np.ndarray) -> np.ndarray:
    """A Schmidt ("consider") update: the error states ``keep`` (a mask) take the measurement, the others keep
    their value (their gain zeroed); the returned P, by the Joseph form, is that estimate's covariance. A filter's
    pose then does not jump where a measurement is about its biases (``rest``)."""
    PHt = P @ H.T
    K = PHt @ small_inv(H @ PHt + Rn)
    K[~keep] = 0.0
    inject(x, K @ r)
    A = np.eye(len(P)) - K @ H
    return A @ P @ A.T + K @ Rn @ K.T


class KnotLog:
    """Filter states at knots. With ``for_smoother`` every knot keeps predicted and filtered state and
    covariance and ``Phi``; without, only output knots keep their filtered state and the block
    ``P[keep, keep]`` of their covariance (``keep`` None: no covariance), so a long run at a high output
    rate holds a few hundred bytes per pose, not the full covariance."""

    def __init__(self, for_smoother: bool, keep: np.ndarray | None = None):
        self.for_smoother = for_smoother
        self.keep = None if keep is None else np.ix_(keep, keep)
        self.t_ns: list[int] = []
        self.output: list[bool] = []
        self.x_pred: list[np.ndarray] = []
        self.P_pred: list[np.ndarray] = []
        self.x_filt: list[np.ndarray] = []
        self.P_filt: list[np.ndarray] = []
        self.Phi: list[np.ndarray] = []
        self._open = False

    def open(self, t_ns: int, x: np.ndarray, P: np.ndarray, Phi: np.ndarray | None) -> bool:
        """Start a knot at ``t_ns`` (the predicted state); no-op (False) when one is already open."""
        if self._open:
            return False
        self._open = True
        self.t_ns.append(t_ns)
        self.output.append(False)
        if self.for_smoother:
            self.x_pred.append(x.copy())
            self.P_pred.append(P.copy())
            self.Phi.append(Phi.copy() if Phi is not None else np.eye(len(P)))
        return True

    def mark_output(self) -> None:
        self.output[-1] = True

    @property
    def is_open(self) -> bool:
        return self._open

    def close(self, x: np.ndarray, P: np.ndarray) -> None:
        """End the open knot with the filtered state; output-only logs drop non-output knots."""
        if not self._open:
            return
        self._open = False
        if self.for_smoother:
            self.x_filt.append(x.copy())
            self.P_filt.append(P.copy())
        elif self.output[-1]:
            self.x_filt.append(x.copy())
            if self.keep is not None:
                self.P_filt.append(P[self.keep])
        else:
            self.t_ns.pop()
            self.output.pop()

    def arrays(self) -> dict[str, np.ndarray]:
        out = {"t_ns": np.asarray(self.t_ns, dtype=np.int64), "output": np.asarray(self.output, dtype=bool)}
        n = len(self.t_ns)
        out["x_filt"] = _rows(self.x_filt) if n else np.zeros((0, 0))
        out["P_filt"] = np.asarray(self.P_filt) if n and self.P_filt else np.zeros((0, 0, 0))
        if self.for_smoother:
            out["x_pred"] = _rows(self.x_pred) if n else np.zeros((0, 0))
            out["P_pred"] = np.asarray(self.P_pred) if n else np.zeros((0, 0, 0))
            out["Phi"] = np.asarray(self.Phi) if n else np.zeros((0, 0, 0))
        return out


def _rows(states: list) -> np.ndarray:
    """States recorded as arrays or as lists of floats (the 3D filter's), as one (N, n) array."""
    if not isinstance(states[0], list):
        return np.asarray(states)
    n = len(states[0])
    return np.fromiter(chain.from_iterable(states), np.float64, n * len(states)).reshape(len(states), n)
