"""The cost behind time-offset estimation: how well two trajectories agree when one is shifted in time.

Both trajectories sit on one time axis (seconds since each one's first stamp; the estimate shifted by x, so
the offset is ``delta_ns = base_ns + x * 1e9`` and floats only hold relative seconds). The smoother trajectory
(lower ``noise_level_m``) is interpolated at the other's stamps: positions with a cubic Hermite, rotations
along the geodesic between samples. Interpolating the noisier one would make the error depend on where its
samples fall (noise averages out between samples) and bias the offset.

At an offset, the pairs are aligned as asked and the mean squared residuals come in closed form from the
pairs' moments, with no fit applied: positions by Umeyama (|b|^2 + |a|^2 - 2 tr(DS); with scale
|b|^2 - tr(DS)^2 / |a|^2) or posyaw (|a|^2 + |b|^2 - 2 (hypot(C, S) + a_z . b_z)); rotations by the constant
rotation R minimising sum |R_ref - R R_est|_F^2 (chordal: 6 - 2 max tr(R^T M) / n, M = mean R_ref R_est^T).
"""

from __future__ import annotations

import numpy as np

from ..geometry import skew, so3_log_batch
from .alignment import posyaw, umeyama
from .association import Trajectory

NOISE_SAMPLE = 5000  # poses used to judge which trajectory is smoother
_CHI2_3_MEDIAN_OVER_3 = 2.365974 / 3.0  # median of a chi-square with 3 dof, per axis


def even_indices(n: int, k: int) -> np.ndarray:
    """At most ``k`` evenly spread indices into ``n`` items, first and last included."""
    return np.unique(np.linspace(0, n - 1, min(n, k)).round().astype(np.int64))


def noise_level_m(stamps_s: np.ndarray, positions: np.ndarray, limit: int = NOISE_SAMPLE) -> float:
    """Robust white-noise level (m per axis) of sampled positions, irregular stamps allowed.

    Each position is compared with the cubic through its two neighbours on either side; smooth motion cancels
    to its fourth derivative, noise does not. The residual is normalised by the noise it would have, so sides
    sampled at different rates compare. NaN with fewer than five poses.
    """
    n = len(stamps_s)
    if n < 5:
        return float("nan")
    i = even_indices(n - 4, limit) + 2
    t = stamps_s[i]
    ks = (-2, -1, 1, 2)
    weights = []
    for a in ks:
        w = np.ones(len(i))
        for b in ks:
            if b != a:
                w *= (t - stamps_s[i + b]) / (stamps_s[i + a] - stamps_s[i + b])
        weights.append(w)
    pred = sum(w[:, None] * positions[i + a] for a, w in zip(ks, weights))
    r2 = np.sum((positions[i] - pred) ** 2, axis=1) / (1.0 + sum(w**2 for w in weights)) / 3.0
    return float(np.sqrt(np.median(r2) / _CHI2_3_MEDIAN_OVER_3))


def hermite_coefficients(t: np.ndarray, p: np.ndarray) -> np.ndarray:
    """(N-1, 4, 3) cubic coefficients per interval, ``p(u) = c0 + u (c1 + u (c2 + u c3))`` for u in [0, 1]:
    cubic Hermite with central-difference velocities (one-sided at the ends)."""
    m = np.empty_like(p)
    m[1:-1] = (p[2:] - p[:-2]) / (t[2:] - t[:-2])[:, None]
    m[0] = (p[1] - p[0]) / (t[1] - t[0])
    m[-1] = (p[-1] - p[-2]) / (t[-1] - t[-2])
    h = np.diff(t)[:, None]
    d, a, b = p[1:] - p[:-1], h * m[:-1], h * m[1:]
    return np.stack([p[:-1], a, 3 * d - 2 * a - b, a + b - 2 * d], axis=1)


def position_msq(src: np.ndarray, dst: np.ndarray, align: str) -> float:
    """Mean squared residual |dst - (s R src + t)|^2 after the best alignment of the mode (closed form)."""
    if align == "none":
        return float(np.mean(np.sum((dst - src) ** 2, axis=1)))
    a, b = src - src.mean(axis=0), dst - dst.mean(axis=0)
    aa, bb = float(np.sum(a * a)), float(np.sum(b * b))
    if align == "posyaw":
        c = float(np.sum(a[:, 0] * b[:, 0] + a[:, 1] * b[:, 1]))
        s = float(np.sum(a[:, 0] * b[:, 1] - a[:, 1] * b[:, 0]))
        r2 = aa + bb - 2.0 * (np.hypot(c, s) + float(np.sum(a[:, 2] * b[:, 2])))
    else:
        U, d, Vt = np.linalg.svd(b.T @ a)
        tr = d[0] + d[1] + d[2] * np.sign(np.linalg.det(U) * np.linalg.det(Vt))  # a rotation, not a reflection
        r2 = (bb - tr * tr / aa if aa > 0 else bb) if align == "sim3" else aa + bb - 2.0 * tr
    return max(r2, 0.0) / len(src)


def best_rotation(M: np.ndarray, align: str) -> np.ndarray:
    """The rotation R (as the mode allows) maximising tr(R^T M), i.e. best aligning R_est onto R_ref."""
    if align == "none":
        return np.eye(3)
    if align == "posyaw":
        yaw = np.arctan2(M[1, 0] - M[0, 1], M[0, 0] + M[1, 1])
        c, s = np.cos(yaw), np.sin(yaw)
        return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])
    U, _, Vt = np.linalg.svd(M)
    S = np.diag([1.0, 1.0, np.sign(np.linalg.det(U) * np.linalg.det(Vt))])
    return U @ S @ Vt


def rotation_msq(M: np.ndarray, n: int, align: str) -> float:
    """Mean chordal residual |R_ref - R R_est|_F^2 for ``M = sum R_ref R_est^T`` over n pairs, R as the mode allows."""
    if align == "none":
        best = np.trace(M)
    elif align == "posyaw":
        best = np.hypot(M[0, 0] + M[1, 1], M[1, 0] - M[0, 1]) + M[2, 2]
    else:
        U, d, Vt = np.linalg.svd(M)
        best = d[0] + d[1] + d[2] * np.sign(np.linalg.det(U) * np.linalg.det(Vt))
    return max(6.0 - 2.0 * float(best) / n, 0.0)


class OffsetCost:
    """Mean squared aligned residuals of two trajectories as a function of the shift x (module doc)."""

    def __init__(self, ref: Trajectory, est: Trajectory, align: str, rotations: bool) -> None:
        self.base_ns = int(ref.stamps_ns[0]) - int(est.stamps_ns[0])
        self.t_ref = (ref.stamps_ns - ref.stamps_ns[0]) / 1e9
        self.t_est = (est.stamps_ns - est.stamps_ns[0]) / 1e9
        self.ref, self.est = ref, est
        self.est_sparse = len(est) <= len(ref)
        noise_ref, noise_est = noise_level_m(self.t_ref, ref.positions), noise_level_m(self.t_est, est.positions)
        known = np.isfinite(noise_ref) and np.isfinite(noise_est)
        # the estimate is queried (the reference interpolated) unless the reference is the noisier one
        self.query_est = not noise_est < noise_ref if known else self.est_sparse
        other = ref if self.query_est else est
        t_o = self.t_ref if self.query_est else self.t_est
        self.coef_o = hermite_coefficients(t_o, other.positions)
        self.rotations = rotations
        if rotations:
            # geodesic interpolation R_k Exp(u phi_k) by Rodrigues: R_k (I + sin(u th) K + (1 - cos(u th)) K^2),
            # K the unit-axis cross matrix of phi_k; the three products with R_k are kept per interval
            R = other.poses[:, :3, :3]
            phi = so3_log_batch(np.einsum("nji,njk->nik", R[:-1], R[1:]))
            self.theta_o = np.linalg.norm(phi, axis=1)
            K = skew(phi / np.where(self.theta_o > 0, self.theta_o, 1.0)[:, None])
            self.rod_o = np.stack([R[:-1], R[:-1] @ K, R[:-1] @ K @ K], axis=1)  # (N-1, 3, 3, 3)
        self.align = align
        self.need = 2 if align in ("none", "posyaw") else 3

    def delta_ns(self, x_s: float) -> int:
        return self.base_ns + int(round(x_s * 1e9))

    def x_s(self, delta_ns: int) -> float:
        return (int(delta_ns) - self.base_ns) / 1e9

    def _times(self, query_est: bool):
        """(query times, other times, sign): query + sign * x is the other's time."""
        return (self.t_est, self.t_ref, 1.0) if query_est else (self.t_ref, self.t_est, -1.0)

    def matches(self, xs: np.ndarray, max_diff_s: float, sample_size: int) -> tuple[np.ndarray, int]:
        """Sampled stamps of the sparser trajectory with a stamp of the other within ``max_diff_s``, per offset."""
        t_s, t_d, sign = self._times(self.est_sparse)
        sample = t_s[even_indices(len(t_s), sample_size)]
        counts = np.zeros(len(xs), dtype=np.int64)
        rows = max(1, 2_000_000 // len(sample))
        for k in range(0, len(xs), rows):
            q = sample[None, :] + sign * xs[k:k + rows, None]
            j = np.clip(np.searchsorted(t_d, q), 1, len(t_d) - 1)
            gap = np.minimum(np.abs(t_d[j] - q), np.abs(t_d[j - 1] - q))
            counts[k:k + rows] = np.count_nonzero(gap <= max_diff_s, axis=1)
        return counts, len(sample)

    def subset(self, k: int) -> tuple[np.ndarray, np.ndarray, np.ndarray | None]:
        """(times, positions, rotations) of at most ``k`` evenly spread stamps of the queried trajectory."""
        t_q = self._times(self.query_est)[0]
        traj = self.est if self.query_est else self.ref
        idx = even_indices(len(t_q), k)
        R = np.ascontiguousarray(traj.poses[idx, :3, :3]) if self.rotations else None
        return t_q[idx], np.ascontiguousarray(traj.positions[idx]), R

    def _pairs(self, x: float, sample, fixed: tuple[float, float] | None, with_rot: bool = True):
        """(inside mask, queried positions, interpolated positions, queried rotations, interpolated rotations)."""
        t_q, t_o, sign = self._times(self.query_est)
        t, p, R = sample
        lo, hi = (x, x) if fixed is None else fixed
        inside = np.ones(len(t), dtype=bool)
        for bound in (lo, hi):
            q = t + sign * bound
            inside &= (q >= t_o[0]) & (q <= t_o[-1])
        if np.count_nonzero(inside) < self.need:
            return inside, None, None, None, None
        q = t[inside] + sign * x
        j = np.clip(np.searchsorted(t_o, q), 1, len(t_o) - 1)
        k = j - 1
        uc = ((q - t_o[k]) / (t_o[j] - t_o[k]))[:, None]
        c = self.coef_o[k]
        other = c[:, 0] + uc * (c[:, 1] + uc * (c[:, 2] + uc * c[:, 3]))  # cubic Hermite
        if not (self.rotations and with_rot):
            return inside, p[inside], other, None, None
        ut = uc[:, 0] * self.theta_o[k]
        rod = self.rod_o[k]
        R_other = rod[:, 0] + np.sin(ut)[:, None, None] * rod[:, 1] + (1.0 - np.cos(ut))[:, None, None] * rod[:, 2]
        return inside, p[inside], other, R[inside], R_other

    def _rotation_sum(self, R_q: np.ndarray, R_other: np.ndarray) -> np.ndarray:
        """``M = sum R_ref R_est^T`` over the pairs, as one (3, 9n) x (9n, 3) product."""
        R_ref, R_est = (R_other, R_q) if self.query_est else (R_q, R_other)
        return np.swapaxes(R_ref, 0, 1).reshape(3, -1) @ np.swapaxes(R_est, 1, 2).reshape(-1, 3)

    def _rotations_of(self, R_q: np.ndarray, R_other: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(R_est, R_ref) per pair."""
        return (R_q, R_other) if self.query_est else (R_other, R_q)

    def _roles(self, mine, other):
        """(estimate side, reference side) of a queried/interpolated pair of arrays."""
        return (mine, other) if self.query_est else (other, mine)

    def residuals(self, x: float, sample, fixed: tuple[float, float] | None = None,
                  with_rot: bool = True) -> tuple[float, float, int]:
        """(position, rotation) mean squared residuals at offset ``x`` and the pairs used (rotation 0 without).

        ``fixed``: keep only the queried stamps that stay inside the other's span for every x in this interval,
        so a scan over it compares the same pairs. Too few pairs give (inf, inf, n).
        """
        inside, p, other, R, R_other = self._pairs(x, sample, fixed, with_rot)
        n = int(np.count_nonzero(inside))
        if p is None:
            return float("inf"), float("inf"), n
        src, dst = self._roles(p, other)  # the estimate is aligned onto the reference
        pos = position_msq(src, dst, self.align)
        if R is None:
            return pos, 0.0, n
        return pos, rotation_msq(self._rotation_sum(R, R_other), n, self.align), n

    def slopes(self, x: float, sample, fixed: tuple[float, float], d: float) -> tuple[np.ndarray, np.ndarray] | None:
        """Per pair, the derivative over x of its squared residual (positions, rotations), each side of ``x``
        aligned by its own fit over all pairs, as the cost is: the block sums of these are the cost's slope
        split over time, which spreads with correlated residuals (drift). None with too few pairs."""
        pos, rot = [], []
        for v in (x - d, x + d):
            _, p, other, R, R_other = self._pairs(v, sample, fixed)
            if p is None:
                return None
            src, dst = self._roles(p, other)
            if self.align == "none":
                A, t = np.eye(3), np.zeros(3)
            elif self.align == "posyaw":
                A, t = posyaw(src, dst)
            else:
                Rot, t, s = umeyama(src, dst, with_scale=self.align == "sim3")
                A = s * Rot
            pos.append(np.sum((dst - (src @ A.T + t)) ** 2, axis=1))
            if self.rotations:
                R_est, R_ref = self._rotations_of(R, R_other)
                Q = best_rotation(np.einsum("nij,nkj->ik", R_ref, R_est), self.align)
                rot.append(6.0 - 2.0 * np.einsum("nji,jk,nki->n", R_ref, Q, R_est))
        dpos = (pos[1] - pos[0]) / (2 * d)
        return dpos, (rot[1] - rot[0]) / (2 * d) if rot else np.zeros_like(dpos)
