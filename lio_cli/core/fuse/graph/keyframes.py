"""Where the factor graph puts its nav states, and the filter's states there (the graph's starting values).

Keyframes: every odometry and GPS stamp (their factors then act on a state at their own instant), plus a grid
of ``KEYFRAME_PERIOD_NS`` where those leave longer stretches; grid stamps closer than ``MIN_SPACING_NS`` to a
measurement stamp are dropped. Measurement stamps within ``MERGE_NS`` of the one before share its keyframe
(``attach``): an IMU factor over microseconds is so stiff that the solver stalls on it. The span's first and
last instants are keyframes, but keyframes closer than ``END_SPACING_NS`` (or half the median spacing, where
less) to the one before them are dropped from the end (the span's end, a measurement there: the outputs after
the last keyframe are the IMU's prediction from it, the measurements after it are left out).
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from ..inputs import FuseOptions
from ..timeline import OUT, Prepared

KEYFRAME_PERIOD_NS = 100_000_000  # 0.1 s: the IMU factor's span, short enough for its first-order bias update
MIN_SPACING_NS = 20_000_000
END_SPACING_NS = 50_000_000  # the last interval's least (or half the median): its far states hang on one factor
MERGE_NS = 50_000  # a measurement this close to the one before shares its keyframe (0.5 mm at 10 m/s)


def keyframe_stamps(prep: Prepared, period_ns: int = KEYFRAME_PERIOD_NS) -> np.ndarray:
    """Sorted int64 keyframe stamps inside the span (module docstring)."""
    t0, t1 = prep.t0_ns, prep.t1_ns
    meas = [np.array([t0, t1], np.int64)]
    for name in ("odom", "gps"):
        s = getattr(prep, name)
        if s is not None and len(s):
            meas.append(s.stamps_ns[(s.stamps_ns >= t0) & (s.stamps_ns <= t1)])
    m = np.unique(np.concatenate(meas))
    keep = np.ones(len(m), bool)
    last = m[0]
    for i in range(1, len(m)):  # against the last kept stamp: a run of close ones folds into its first
        if m[i] - last < MERGE_NS and i < len(m) - 1:
            keep[i] = False
        else:
            last = m[i]
    m = m[keep]
    grid = np.arange(t0, t1, period_ns, dtype=np.int64)
    j = np.clip(np.searchsorted(m, grid), 1, len(m) - 1)
    near = np.minimum(np.abs(grid - m[j - 1]), np.abs(m[j] - grid))
    kt = np.unique(np.concatenate([m, grid[near >= MIN_SPACING_NS]]))
    if len(kt) > 2:
        least = min(END_SPACING_NS, int(np.median(np.diff(kt))) // 2)
        while len(kt) > 2 and kt[-1] - kt[-2] < least:
            kt = kt[:-1]
    return kt


def attach(kt: np.ndarray, stamps_ns: np.ndarray) -> np.ndarray:
    """The keyframe of each measurement stamp: its own, or the one it was merged into (``MERGE_NS``)."""
    j = np.clip(np.searchsorted(kt, stamps_ns), 1, len(kt) - 1)
    return np.where(stamps_ns - kt[j - 1] < kt[j] - stamps_ns, j - 1, j)


def with_outputs(prep: Prepared, stamps: np.ndarray) -> Prepared:
    """``prep`` with its output events at ``stamps`` instead (same order rule: outputs last at a stamp)."""
    keep = prep.kinds != OUT
    t = np.concatenate([prep.times[keep], stamps])
    k = np.concatenate([prep.kinds[keep], np.full(len(stamps), OUT, np.int8)])
    i = np.concatenate([prep.index[keep], np.arange(len(stamps))])
    order = np.lexsort((k, t))
    return replace(prep, out_stamps=stamps, times=t[order], kinds=k[order], index=i[order])


def filter_options(o: FuseOptions) -> FuseOptions:
    """The filter pass under the graph: no RTS record (its memory grows with the log); its pose covariance kept
    (the chunks' priors at their seams)."""
    return replace(o, smooth=False, want_covariance=True)
