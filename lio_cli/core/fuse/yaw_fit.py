"""The fit behind ``wheel_yaw``: ``d = b_j + b'_j tc + c g`` (a bias line per chunk j, ``c`` the wheels' yaw scale
off the gyro's ``g``) by least squares from per-chunk normal equations, far samples trimmed, ``c``'s sigma the
larger of the fit's and a block jackknife's; the residual's share of the speed."""

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


def _normal_equations(inv: np.ndarray, tc: np.ndarray, g: np.ndarray, d: np.ndarray,
                      keep: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """``X^T X`` and ``X^T d`` over the kept samples of ``d = b_j + b'_j tc + c g`` (chunk j = ``inv``), summed per
    chunk: (2m+1)^2 whatever the log's length (the design matrix itself is one row per sample)."""
    m = int(inv.max()) + 1
    j, t, gk, dk = inv[keep], tc[keep], g[keep], d[keep]
    s = lambda w: np.bincount(j, weights=w, minlength=m)  # noqa: E731
    A = np.zeros((2 * m + 1, 2 * m + 1))
    b, a = np.arange(0, 2 * m, 2), np.arange(1, 2 * m, 2)
    A[b, b], A[b, a], A[a, a] = s(np.ones(len(j))), s(t), s(t * t)
    A[a, b] = A[b, a]
    A[b, -1], A[a, -1] = s(gk), s(t * gk)
    A[-1, b], A[-1, a] = A[b, -1], A[a, -1]
    A[-1, -1] = float(gk @ gk)
    rhs = np.concatenate([np.column_stack([s(dk), s(t * dk)]).ravel(), [float(gk @ dk)]])
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


def _jackknife_sigma(tw: np.ndarray, inv: np.ndarray, tc: np.ndarray, g: np.ndarray, d: np.ndarray,
                     keep: np.ndarray, A: np.ndarray, rhs: np.ndarray) -> float:
    """The scale's sigma from the fit repeated without each ``JACKKNIFE_S`` block in turn (at most ``MAX_BLOCKS``,
    longer on a long log): a slip's edges and the body's sway are correlated over a block, which the residual's
    white sigma does not count; 0 where there are fewer than ``MIN_BLOCKS`` blocks."""
    length = max(JACKKNIFE_S, (tw[-1] - tw[0]) / MAX_BLOCKS)  # each refit costs the whole log
    block = np.floor((tw - tw[0]) / length).astype(np.int64)
    blocks = np.unique(block[keep])
    if len(blocks) < MIN_BLOCKS:
        return 0.0
    cs = []
    for b in blocks.tolist():
        Ab, rb = _normal_equations(inv, tc, g, d, keep & (block == b))
        cs.append(float(np.linalg.lstsq(A - Ab, rhs - rb, rcond=None)[0][-1]))
    cs = np.asarray(cs)
    return float(np.sqrt((len(cs) - 1) / len(cs) * np.sum((cs - cs.mean()) ** 2)))


@dataclass
class Fit:
    """``d = b_j + b'_j tc + c g`` fitted with far samples trimmed (a run of them widened by ``TRIM_EDGE_S``): the
    residual, its robust sigma, the kept samples, ``c`` and its sigma (the larger of the fit's and the
    jackknife's). The last trim is judged on the pass before it, so a kept sample may lie just past it after."""

    r: np.ndarray
    sigma: float
    keep: np.ndarray
    c: float
    c_sigma: float

    @classmethod
    def of(cls, tw: np.ndarray, inv: np.ndarray, tc: np.ndarray, g: np.ndarray, d: np.ndarray) -> Fit:
        keep = np.ones(len(d), bool)
        for _ in range(TRIM_PASSES):  # a slip's run widened: its onset and end, below the trim, bias the scale
            A, rhs = _normal_equations(inv, tc, g, d, keep)
            sol = np.linalg.lstsq(A, rhs, rcond=None)[0]
            r = d - sol[2 * inv] - sol[2 * inv + 1] * tc - sol[-1] * g
            sigma = robust_sigma(r[keep], centre=False)
            keep = ~widened(tw, np.abs(r) > TRIM_Z * max(sigma, 1e-12), TRIM_EDGE_S)
        A, rhs = _normal_equations(inv, tc, g, d, keep)  # the last trim's samples solved again: c is theirs
        sol = np.linalg.lstsq(A, rhs, rcond=None)[0]
        r = d - sol[2 * inv] - sol[2 * inv + 1] * tc - sol[-1] * g
        sigma = robust_sigma(r[keep], centre=False)
        s2 = float(r[keep] @ r[keep]) / max(int(keep.sum()) - len(A), 1)
        formal = float(np.sqrt(max((s2 * np.linalg.pinv(A))[-1, -1], 0.0)))
        return cls(r, sigma, keep, float(sol[-1]), max(formal, _jackknife_sigma(tw, inv, tc, g, d, keep, A, rhs)))


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
