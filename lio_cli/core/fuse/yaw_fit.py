"""The fit behind ``wheel_yaw``: ``d = b_j + b'_j tc + Z k`` (a bias line per chunk j, ``k`` the regressors' shares
over the whole log) by least squares from per-chunk normal equations, far samples trimmed, ``k``'s sigma the
larger of the fit's and a block jackknife's."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..robust import robust_sigma

TRIM_Z = 4.0
TRIM_PASSES = 3
TRIM_EDGE_S = 1.0  # a run of trimmed samples (a slip) widened by this: its edges below the trim bias the scale
JACKKNIFE_S = 5.0  # the sigma from the fit without each block this long in turn
MIN_BLOCKS = 5
MAX_BLOCKS = 24


def _normal_equations(inv: np.ndarray, tc: np.ndarray, Z: np.ndarray, d: np.ndarray,
                      keep: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """``X^T X`` and ``X^T d`` over the kept samples of ``d = b_j + b'_j tc + Z k`` (chunk j = ``inv``; ``Z`` a
    column per regressor of the whole log), summed per chunk: (2m+p)^2 whatever the log's length (the design
    matrix itself is one row per sample)."""
    m, p = int(inv.max()) + 1, Z.shape[1]
    j, t, zk, dk = inv[keep], tc[keep], Z[keep], d[keep]
    s = lambda w: np.bincount(j, weights=w, minlength=m)  # noqa: E731
    A = np.zeros((2 * m + p, 2 * m + p))
    b, a = np.arange(0, 2 * m, 2), np.arange(1, 2 * m, 2)
    A[b, b], A[b, a], A[a, a] = s(np.ones(len(j))), s(t), s(t * t)
    A[a, b] = A[b, a]
    for q in range(p):
        A[b, 2 * m + q], A[a, 2 * m + q] = s(zk[:, q]), s(t * zk[:, q])
        A[2 * m + q, b], A[2 * m + q, a] = A[b, 2 * m + q], A[a, 2 * m + q]
    A[2 * m:, 2 * m:] = zk.T @ zk
    rhs = np.concatenate([np.column_stack([s(dk), s(t * dk)]).ravel(), zk.T @ dk])
    return A, rhs


def widened(t: np.ndarray, far: np.ndarray, edge_s: float) -> np.ndarray:
    """``far`` with every run of two or more far samples widened by ``edge_s`` on each side (sorted ``t``)."""
    run = np.flatnonzero(far & (np.r_[far[1:], False] | np.r_[False, far[:-1]]))
    if not len(run):
        return far
    edge = np.zeros(len(t) + 1)
    np.add.at(edge, np.searchsorted(t, t[run] - edge_s), 1)
    np.add.at(edge, np.searchsorted(t, t[run] + edge_s, side="right"), -1)
    return far | (np.cumsum(edge)[:-1] > 0)


def _jackknife_sigmas(tw: np.ndarray, inv: np.ndarray, tc: np.ndarray, Z: np.ndarray, d: np.ndarray,
                      keep: np.ndarray, A: np.ndarray, rhs: np.ndarray) -> np.ndarray:
    """The regressors' sigmas from the fit repeated without each ``JACKKNIFE_S`` block in turn (at most
    ``MAX_BLOCKS``, longer on a long log): a slip's edges and the body's sway are correlated over a block, which
    the residual's white sigma does not count; zeros where there are fewer than ``MIN_BLOCKS`` blocks."""
    p = Z.shape[1]
    length = max(JACKKNIFE_S, (tw[-1] - tw[0]) / MAX_BLOCKS)  # each refit costs the whole log
    block = np.floor((tw - tw[0]) / length).astype(np.int64)
    blocks = np.unique(block[keep])
    if len(blocks) < MIN_BLOCKS:
        return np.zeros(p)
    ks = []
    for b in blocks.tolist():
        Ab, rb = _normal_equations(inv, tc, Z, d, keep & (block == b))
        ks.append(np.linalg.lstsq(A - Ab, rhs - rb, rcond=None)[0][-p:])
    ks = np.asarray(ks)
    return np.sqrt((len(ks) - 1) / len(ks) * np.sum((ks - ks.mean(axis=0)) ** 2, axis=0))


@dataclass
class Fit:
    """``d = b_j + b'_j tc + Z k`` fitted with far samples trimmed (a run of them widened by ``TRIM_EDGE_S``):
    the residual, its robust sigma, the kept samples, ``k`` and its sigmas (the larger of the fit's and the
    jackknife's)."""

    r: np.ndarray
    sigma: float
    keep: np.ndarray
    k: np.ndarray
    k_sigma: np.ndarray

    @classmethod
    def of(cls, tw: np.ndarray, inv: np.ndarray, tc: np.ndarray, Z: np.ndarray, d: np.ndarray) -> Fit:
        m, p = int(inv.max()) + 1, Z.shape[1]
        keep = np.ones(len(d), bool)
        for _ in range(TRIM_PASSES):  # a slip's run widened: its onset and end, below the trim, bias the scale
            A, rhs = _normal_equations(inv, tc, Z, d, keep)
            sol = np.linalg.lstsq(A, rhs, rcond=None)[0]
            r = d - sol[2 * inv] - sol[2 * inv + 1] * tc - Z @ sol[2 * m:]
            sigma = robust_sigma(r[keep], centre=False)
            keep = ~widened(tw, np.abs(r) > TRIM_Z * max(sigma, 1e-12), TRIM_EDGE_S)
        A, rhs = _normal_equations(inv, tc, Z, d, keep)
        s2 = float(r[keep] @ r[keep]) / max(int(keep.sum()) - len(A), 1)
        formal = np.sqrt(np.maximum(np.diag(s2 * np.linalg.pinv(A))[-p:], 0.0))
        return cls(r, sigma, keep, sol[-p:], np.maximum(formal, _jackknife_sigmas(tw, inv, tc, Z, d, keep, A, rhs)))


def speed_share(inv: np.ndarray, v: np.ndarray, fit: Fit) -> tuple[float, float, float]:
    """The residual's share of the speed (rad/m) with the speed's mean per chunk taken out (the bias line holds
    a steady speed's share), its sigma, and the yaw rate it makes (rms, rad/s)."""
    keep = fit.keep & np.isfinite(v)  # a sanitised (NaN) speed says nothing of its share
    v = np.nan_to_num(v)
    vc = v - (np.bincount(inv, v * keep) / np.maximum(np.bincount(inv, keep.astype(float)), 1.0))[inv]
    ss = float(vc[keep] @ vc[keep])
    if ss <= 0:
        return 0.0, np.inf, 0.0
    e = float(vc[keep] @ fit.r[keep]) / ss
    return e, fit.sigma / np.sqrt(ss), abs(e) * float(np.sqrt(ss / np.count_nonzero(keep)))
