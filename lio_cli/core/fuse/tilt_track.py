"""The base's forward acceleration from the IMU for the wheel-scale check (``wheel_slip``), with the up direction
in the base frame tracked over the log: anchored from the accelerometer at the start of each ``SEGMENT_S``-long
stretch (the accelerometer less the wheels' acceleration over its first second) and carried by the gyro alone
within it, so the gyro's bias walk never tilts it for more than one stretch. Each stretch brings its own four
linear terms (the gyro's x and y bias, the anchor's tilt error about x and y), which the scale fit solves for;
a log shorter than two stretches is one stretch, anchored at its first second. Also the gyro's angle random walk
(``angle_walk_q``) and the covariance it gives the speed track's increments (``walk_variance``), restarted at
each anchor."""

from __future__ import annotations

import numpy as np

from ...so3 import so3_exp
from ..imu import running_integral
from ..robust import white_variance

MOUNT_WINDOW_S = 1.0  # the up direction's windows for the mount's pitch (``mount_cosine``)
SEGMENT_S = 30.0  # the up direction is re-anchored from the accelerometer this often (the log split evenly)
WALK_BANDS = (1, 2, 4)  # samples per mean for the gyro's noise density (2 and 4 cancel a vibration at half the rate)


def segment_starts(t_s: np.ndarray) -> np.ndarray:
    """IMU indices where a stretch starts: the log split into as many equal stretches of at least
    ``SEGMENT_S`` as fit (one for a log shorter than two)."""
    n = max(1, int((t_s[-1] - t_s[0]) // SEGMENT_S))
    # an IMU gap longer than a stretch puts two starts on one sample: the empty stretch goes
    return np.unique(np.searchsorted(t_s, t_s[0] + (t_s[-1] - t_s[0]) * np.arange(n) / n))


def forward_accel(t_s: np.ndarray, f_b: np.ndarray, w_b: np.ndarray, t_w: np.ndarray, v_w: np.ndarray,
                  g: float, gap: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(a, sens, starts): the forward acceleration (``carried``) of each stretch (``segment_starts``), its
    (N, 4) sensitivities to the four terms of the sample's own stretch, and the stretches' start indices."""
    starts = segment_starts(t_s)
    a, sens = np.empty(len(t_s)), np.empty((len(t_s), 4))
    ends = np.append(starts[1:], len(t_s))
    c = mount_cosine(t_s, f_b, w_b, t_w, v_w)
    for i, j in zip(starts, ends):
        a[i:j], sens[i:j] = carried(t_s[i:j], f_b[i:j], w_b[i:j], t_w, v_w, g, gap[i:j - 1], c)
    return a, sens, starts


def mount_cosine(t_s: np.ndarray, f_b: np.ndarray, w_b: np.ndarray, t_w: np.ndarray, v_w: np.ndarray) -> float:
    """The cosine of the IMU mount's pitch: the median, weighted by the distance driven in each, over
    ``MOUNT_WINDOW_S`` windows of the up direction's forward share (the accelerometer less the wheels'
    acceleration). The ground's grade at any one moment is not the mount's: over a drive up and down hills it
    averages out along the distance, where the first second's (or a long wait parked on a slope) would stay in.
    A log that hardly moves: every window alike."""
    dt = float(np.median(np.diff(t_s))) if len(t_s) > 1 else 0.0
    n = max(1, int(round(MOUNT_WINDOW_S / dt))) if dt > 0 else 1
    m = len(t_s) // n
    if m < 1:
        return 1.0
    v = np.interp(t_s, t_w, v_w)
    kin = np.column_stack([np.interp(t_s, t_w, np.gradient(v_w, t_w)), v * w_b[:, 2], -v * w_b[:, 1]])
    up = (f_b - kin)[:m * n].reshape(m, n, 3).mean(axis=1)
    up /= np.maximum(np.linalg.norm(up, axis=1, keepdims=True), 1e-9)
    w = np.abs(v[:m * n]).reshape(m, n).mean(axis=1)
    if not np.isfinite(w).all() or w.sum() <= 0.0:
        w = np.ones(m)
    keep = w > 0.0
    x, w = up[keep, 0], w[keep]
    order = np.argsort(x)
    mid = np.cumsum(w[order]) - 0.5 * w[order]  # each window's middle along the sorted weight
    ux = float(np.interp(0.5 * w.sum(), mid, x[order]))  # equal weights: np.median's value
    return float(np.sqrt(max(1.0 - ux**2, 1e-6)))


class StretchIntegral:
    """The running trapezoid integral, at stamps ``t``, of the sensitivities ``forward_accel`` gives: as the
    (n, 4 * stretches) matrix whose stretch-k columns are zero before that stretch and hold its total after it,
    kept per stretch (memory linear in the log where the matrix grows with its square). ``G[j]`` is row j,
    ``G @ c`` the matrix times c; steps across an IMU gap (``gap``, one per step) add nothing."""

    def __init__(self, t: np.ndarray, t_s: np.ndarray, sens: np.ndarray, starts: np.ndarray, gap: np.ndarray):
        ends = np.append(starts[1:], len(t_s))
        self.n = len(t)
        self.total = np.zeros((len(starts), 4))
        self.parts = []  # per stretch: (first stamp after it starts, first stamp at its total, values between)
        for k, (i, j) in enumerate(zip(starts, ends)):
            lo, hi = max(int(i) - 1, 0), min(int(j), len(t_s) - 1)
            x = sens[lo:hi + 1].copy()
            x[:i - lo] = 0.0  # the sample before the stretch and the one after it belong to its neighbours
            x[j - lo:] = 0.0
            X = running_integral(t_s[lo:hi + 1], x, gap[lo:hi])
            a, b = int(np.searchsorted(t, t_s[lo], "right")), int(np.searchsorted(t, t_s[hi], "left"))
            vals = np.column_stack([np.interp(t[a:b], t_s[lo:hi + 1], X[:, q]) for q in range(4)])
            self.total[k] = X[-1]
            self.parts.append((a, b, vals))

    def __getitem__(self, j: int) -> np.ndarray:
        row = np.zeros(self.total.size)
        for k, (a, b, vals) in enumerate(self.parts):
            if j >= b:
                row[4 * k:4 * k + 4] = self.total[k]
            elif j >= a:
                row[4 * k:4 * k + 4] = vals[j - a]
        return row

    def __matmul__(self, c: np.ndarray) -> np.ndarray:
        out = np.zeros(self.n)
        for k, (a, b, vals) in enumerate(self.parts):
            ck = c[4 * k:4 * k + 4]
            out[a:b] += vals @ ck
            out[b:] += self.total[k] @ ck
        return out


def carried(t_s: np.ndarray, f_b: np.ndarray, w_b: np.ndarray, t_w: np.ndarray, v_w: np.ndarray,
            g: float, gap: np.ndarray, c: float) -> tuple[np.ndarray, np.ndarray]:
    """The base's forward acceleration (m/s^2) at the IMU stamps, ``f_x`` plus gravity's forward share, over the
    cosine ``c`` of the IMU mount's pitch (``mount_cosine``: a pitched x axis feels that share of the forward
    acceleration): the up direction in the base frame from the first second (the accelerometer less the wheels'
    acceleration), carried by the gyro alone (``du/dt = -w x u``), never pulled by the wheels whose scale it
    measures. Also (N,4) its sensitivities to the gyro's x and y bias and to a start tilt error about x and y
    (propagated with the same rotation), which ``_fit_scale`` solves for. Steps across an IMU gap (``gap``, one
    per step) rotate nothing: the gyro sample after a gap never covers the gap's length."""
    n0 = max(1, int(np.searchsorted(t_s, t_s[0] + 1.0)))
    v = np.interp(t_s[:n0], t_w, v_w)
    a_w = np.interp(t_s[:n0], t_w, np.gradient(v_w, t_w))
    kin = np.column_stack([a_w, v * w_b[:n0, 2], -v * w_b[:n0, 1]])
    u = (f_b[:n0] - kin).mean(axis=0)
    u = u / max(float(np.linalg.norm(u)), 1e-9)
    dt = np.diff(t_s, prepend=t_s[0])
    dt[1:][gap] = 0.0
    R = running_rotation(w_b, dt)  # the base's rotation since the first sample
    ub = np.einsum("nji,j->ni", R, u)  # R^T u
    B = np.cumsum(R * dt[:, None, None], axis=0)  # integral of R: the gyro bias's rotation error is R^T B b
    sens = np.empty((len(t_s), 4))
    for j, e in enumerate(np.eye(3)[:2]):
        phi = np.einsum("nji,nj->ni", R, B @ e)
        sens[:, j] = np.cross(ub, phi)[:, 0]
        sens[:, 2 + j] = np.einsum("nji,j->ni", R, np.cross(e, u))[:, 0]
    return (f_b[:, 0] - g * ub[:, 0]) / c, -g * sens / c


def running_rotation(w_b: np.ndarray, dt: np.ndarray, R0: np.ndarray | None = None) -> np.ndarray:
    """(N,3,3) rotations of the base since before the first sample (``R0`` then, identity without it): the running
    product of ``exp(w dt)``, in log2(N) batched steps."""
    R = so3_exp(w_b * dt[:, None])
    step = 1
    while step < len(R):
        R = np.concatenate([R[:step], R[:-step] @ R[step:]])
        step *= 2
    return R if R0 is None else R0 @ R


def walk_variance(spans: np.ndarray, anchors: np.ndarray) -> np.ndarray:
    """(n,n) covariance of the integrals over time-ordered, non-overlapping ``spans`` (n,2) of a unit Wiener
    process W restarted at each of ``anchors`` (s, ascending, the first at or before the first span; a span
    belongs to the last anchor at or before its start): ``E[W(s) W(u)] = min(s, u)`` from the anchor, so two
    spans [a, b] before [c, d] of one anchor share ``(b^2 - a^2) / 2 * (d - c)``, one with itself
    ``a h^2 + h^3 / 3`` (h = b - a), spans of different anchors nothing."""
    seg = np.maximum(np.searchsorted(anchors, spans[:, 0], side="right") - 1, 0)
    rel = spans - anchors[seg][:, None]
    a, b = rel[:, 0], rel[:, 1]
    h = b - a
    K = np.outer(0.5 * (b * b - a * a), h)
    K = np.triu(K, 1)
    K = K + K.T
    K[np.diag_indices_from(K)] = a * h * h + h**3 / 3.0
    if len(anchors) > 1:
        K[seg[:, None] != seg[None, :]] = 0.0
    return K


def angle_walk_q(t_s: np.ndarray, w: np.ndarray) -> float:
    """The white-noise density squared (rad^2/s) of a gyro axis ``w`` sampled at ``t_s``: the second differences
    of its means over n samples have 6 / n times the per-sample variance, which times the period is the density
    squared. Motion adds to the low bands and vibration to the high ones, white noise is flat: the least over
    ``WALK_BANDS``."""
    dt = float(np.median(np.diff(t_s))) if len(t_s) > 1 else 0.0
    q = []
    for n in WALK_BANDS:
        m = len(w) // n
        if m >= 3:
            y = w[:m * n].reshape(m, n).mean(axis=1)
            q.append(white_variance(y) * n * dt)
    return min(q, default=0.0)
