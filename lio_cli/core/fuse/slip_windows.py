"""Slip windows of the wheel minus IMU speed difference (``wheel_slip``'s detection): a jump of the difference
beyond the chi-square bound of ``gate_probability`` (the sigma measured robustly) and ``MIN_SLIP_REL`` of the
speed opens a window, the difference back at its level before closes it; ``guard`` gives the first fit's
windows around the raw difference's jumps."""

from __future__ import annotations

import numpy as np

from ..robust import robust_sigma

JUMP_S = 0.3  # the wheel minus IMU speed's change over this long finds a slip's onset and end
DRIFT_S = 3.0  # that change less its running median over this long
GUARD_S = 1.0  # the first fit leaves out this much around each jump
LEVEL_S = 0.5  # a slip lasts until the difference is back at its level over this long before it
EDGE_S = 0.25  # a slip window widened by this each side
SIGMA_FLOOR_MPS = 0.01  # the departure's sigma never below this (noise-free simulated wheels)
MIN_SLIP_REL = 0.05  # and a slip departs by at least this share of the speed


def merge(t: np.ndarray, runs: list[tuple[int, int]], pad_s: float) -> list[tuple[int, int]]:
    """Index runs (in order) widened by ``pad_s`` each side, overlapping or touching ones merged."""
    out: list[tuple[int, int]] = []
    for a, b in runs:
        a = int(np.searchsorted(t, t[a] - pad_s))
        b = int(np.searchsorted(t, t[b] + pad_s, side="right")) - 1
        if out and a <= out[-1][1] + 1:
            out[-1] = (out[-1][0], max(out[-1][1], b))
        else:
            out.append((a, b))
    return out


def windows(mask: np.ndarray, t: np.ndarray) -> list[tuple[int, int]]:
    """Index runs [a, b] of ``mask``, each widened by ``EDGE_S``, overlapping ones merged."""
    idx = np.flatnonzero(np.diff(np.concatenate([[0], mask.astype(np.int8), [0]])))
    return merge(t, list(zip(idx[::2], idx[1::2] - 1)), EDGE_S)


def threshold(t: np.ndarray, d: np.ndarray, v: np.ndarray, inside: np.ndarray,
               z: float) -> tuple[np.ndarray, np.ndarray]:
    """(r, thr): ``d``'s change over ``JUMP_S`` and the bound a slip's change exceeds, ``z`` robust sigmas of
    ``r`` and ``MIN_SLIP_REL`` of the speed."""
    m = max(1, int(np.searchsorted(t, t[0] + JUMP_S)))
    r = np.zeros(len(d))
    r[m:] = d[m:] - d[:-m]
    r -= running_median(t, r, DRIFT_S)  # a slowly drifting difference (tilt, bias) is no slip
    ri = r[inside]
    sigma = max(robust_sigma(ri), SIGMA_FLOOR_MPS)
    return r, np.maximum(z * sigma, MIN_SLIP_REL * np.abs(v))


def detect(t: np.ndarray, d: np.ndarray, v: np.ndarray, inside: np.ndarray, z: float) -> list[tuple[int, int]]:
    """Slip windows of ``d`` (wheel minus IMU speed, bias and scale removed): from a jump beyond the bound
    (``threshold``) until ``d`` is back within half of it of its level before the jump (``LEVEL_S``) or the
    log ends, however long (``wheel_slip`` keeps one longer than its MAX_SLIP_S out of the fit); widened by
    ``EDGE_S``."""
    r, thr = threshold(t, d, v, inside, z)
    m = max(1, int(np.searchsorted(t, t[0] + JUMP_S)))
    n_ref = max(1, int(np.searchsorted(t, t[0] + LEVEL_S)))
    mask = np.zeros(len(d), bool)
    k = 0
    while k < len(d):
        if not (inside[k] and abs(r[k]) > thr[k]):
            k += 1
            continue
        a = max(k - m, 0)
        level = float(np.median(d[max(a - n_ref, 0):a + 1]))
        j = k
        while j < len(d) and abs(d[j] - level) > 0.5 * thr[j]:
            j += 1
        mask[a:j] = True
        k = max(j, k + 1)
        while k < len(d) and abs(r[k]) > thr[k]:  # the slip's own end, not another onset
            k += 1
    return windows(mask, t)


def guard(t: np.ndarray, d: np.ndarray, v: np.ndarray, inside: np.ndarray,
           z: float) -> tuple[list[tuple[int, int]], list[tuple[int, int]]]:
    """Windows of ``GUARD_S`` around every jump of ``d`` (kept out of the first fit): (paired, plain). Paired:
    one leaving ``d`` departed spans up to the next bringing it back (or the log's end), a long slip's middle
    out too."""
    r, thr = threshold(t, d, v, inside, z)
    wins = merge(t, [(k, k) for k in np.flatnonzero(inside & (np.abs(r) > thr))], GUARD_S)
    m = max(1, int(np.searchsorted(t, t[0] + JUMP_S)))
    out: list[tuple[int, int]] = []
    opened, at = 0.0, 0  # the open departure's sign and its window
    for a, b in wins:
        step = r[a + m:b + 1:m].sum()  # d's change across the window, its drift taken out
        move = float(np.sign(step)) if abs(step) > max(thr[a], thr[b]) else 0.0
        if opened and move == -opened:
            out[at:] = [(out[at][0], b)]
            opened = 0.0
        else:
            out.append((a, b))
            if move and not opened:
                opened, at = move, len(out) - 1
    if opened:  # never back: out to the log's end
        out[at:] = [(out[at][0], len(t) - 1)]
    return out, wins


def running_median(t: np.ndarray, x: np.ndarray, width_s: float) -> np.ndarray:
    """The median of ``x`` over ``width_s`` centred on each sample: of every sample about 0.1 s apart (the
    series' ends mirrored), interpolated back."""
    step = max(1, int(round(0.1 * (len(t) - 1) / max(t[-1] - t[0], 1e-9))))
    ts, xs = t[::step], x[::step]
    half = max(1, int(round(0.5 * width_s / 0.1)))
    if len(xs) <= half:
        return np.full_like(x, np.median(x))
    padded = np.pad(xs, half, mode="reflect")
    med = np.median(np.lib.stride_tricks.sliding_window_view(padded, 2 * half + 1), axis=1)
    return np.interp(t, ts, med)
