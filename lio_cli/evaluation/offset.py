"""Estimating a constant time offset between an estimate's and a reference's stamps.

The offset ``delta`` is what ``--t-offset`` means: seconds added to the estimate's stamps to put them on the
reference's clock. Three stages, each on what the previous one kept:

1. Matches: over the search range (default: every offset at which the two time spans overlap by at least
   half the shorter one), count on a grid how many stamps of the sparser trajectory find a stamp of the
   denser one within ``max_diff`` (a sample of at most ``MATCH_SAMPLE`` stamps; grid step ``max_diff``, at
   most ``MATCH_GRID_MAX`` points). Offsets reaching ``NEAR_BEST`` of the best count are candidates.
2. Coarse error: at up to ``COARSE_CANDIDATES`` candidates, the aligned error (``offset_cost``): the smoother
   trajectory interpolated at the other's shifted stamps, the pairs aligned as asked (``COST_ALIGNMENT``).
   Positions always; rotations too unless a trajectory is position-only. Here the two mean squared residuals
   are each divided by their smallest value over the offsets tried and averaged.
3. Refinement: grids of 21 offsets around the coarse best, each 5x finer, until the step is below
   ``FULL_DATA_STEP_S``; then, for positions and rotations separately, one such grid on all poses (up to
   ``FINE_SAMPLE``) and a bounded scalar search between its best point's neighbours, to ``FINE_STEP_S``. Each gets a
   precision: how much the slope of its cost varies between consecutive blocks of pairs, over the cost's
   curvature (a sandwich estimate: correlated residuals widen it, where a formula assuming white ones would
   not), but never less than the white-residual formula (with few informative blocks the sandwich collapses),
   and the more precise one decides. Drift of an odometry's positions makes its position residuals
   large and correlated, which biases them by milliseconds while the rotations stay sharp; a trajectory in
   another body frame does the opposite. When the two disagree beyond their precision, a note says so.

Cost is O(range / max_diff * MATCH_SAMPLE + N): it does not grow with how far apart two clocks are.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from ..minimize import minimize_bounded
from ..errors import InputError
from .association import Trajectory
from .offset_cost import OffsetCost, even_indices

# The alignment the cost uses for each --align: origin fits one pose and scale no rotation, so the error
# after them mixes misalignment into the time offset; se3 and sim3 stand in for them.
COST_ALIGNMENT = {"none": "none", "se3": "se3", "sim3": "sim3", "scale": "sim3", "origin": "se3", "posyaw": "posyaw"}
MATCH_GRID_MAX = 4000
MATCH_SAMPLE = 250
NEAR_BEST = 0.9
COARSE_CANDIDATES = 100
COARSE_SAMPLE = 1000
FINE_SAMPLE = 50000
FULL_DATA_STEP_S = 5e-3
FINE_STEP_S = 1e-6
GRID_HALF = 10  # refinement grids hold 2 * GRID_HALF + 1 offsets
SENSITIVITY_S = 0.1  # the cost is probed this far either side of the estimate to judge how well it is defined
# a precision worse than this marks a poorly defined offset (a relative rise of the cost says little: over
# thousands of pairs a rise of 0.1 % can pin the offset to a millisecond)
FLAT_PRECISION_S = 0.02
CURVATURE_S = 1e-3  # the precision comes from the curvature over this much either side
PRECISION_BLOCKS = 16
DISAGREE_SIGMAS = 3.0
FLOOR_POS_M2 = 1e-10  # smallest mean squared residuals used as weights (noise-free data): 10 um
FLOOR_ROT = 2e-12  # chordal, about 1 urad
ZOOM_S = 0.25  # the plotted close-up covers this far either side of the estimate
ZOOM_HALF = 12
_TERMS = ("positions", "rotations")


@dataclass
class OffsetEstimate:
    """The offset found for one estimate, how it was found, and the curves behind it (for plots)."""

    offset_ns: int
    range_ns: tuple[int, int]
    alignment: str  # the alignment of the cost
    rmse_m: float  # aligned translation RMSE of the interpolated pairs at the offset
    rot_rmse_deg: float | None  # aligned rotation RMSE there (None: positions only)
    best_matches: int  # stage 1: most sampled stamps paired at one offset
    sampled: int  # stage 1: stamps sampled
    rise: float | None  # relative cost increase SENSITIVITY_S either side of the offset (None: no pairs there)
    precision_s: float | None  # formal 1-sigma of the offset (white residuals assumed; None: flat cost)
    decided_by: str  # "positions" or "rotations"
    by_term: dict  # term -> {"offset_s", "precision_s"}
    note: str | None = None  # set when the motion barely determines the offset, or the terms disagree
    grid_ns: np.ndarray = field(default_factory=lambda: np.zeros(0, np.int64), repr=False)
    grid_matches: np.ndarray = field(default_factory=lambda: np.zeros(0, np.int64), repr=False)
    curve_ns: np.ndarray = field(default_factory=lambda: np.zeros(0, np.int64), repr=False)
    curve_cost: np.ndarray = field(default_factory=lambda: np.zeros(0), repr=False)  # relative to its minimum
    zoom_ns: np.ndarray = field(default_factory=lambda: np.zeros(0, np.int64), repr=False)
    zoom_cost: np.ndarray = field(default_factory=lambda: np.zeros(0), repr=False)

    @property
    def offset_s(self) -> float:
        return self.offset_ns / 1e9

    def summary(self) -> dict:
        return {"offset_s": self.offset_s, "search_range_s": [self.range_ns[0] / 1e9, self.range_ns[1] / 1e9],
                "cost_alignment": self.alignment, "rmse_m": self.rmse_m, "rot_rmse_deg": self.rot_rmse_deg,
                "matches_sampled": {"best": self.best_matches, "of": self.sampled},
                "precision_s": self.precision_s, "decided_by": self.decided_by, "by_term": self.by_term,
                "relative_rise_at_0.1s": self.rise, "note": self.note}


class _Objective:
    """Position and/or rotation mean squares, each divided by its floor (module doc, stage 2)."""

    def __init__(self, cost: OffsetCost, terms: tuple[int, ...]) -> None:
        self.cost = cost
        self.terms = terms  # 0 positions, 1 rotations
        self.floors = (1.0, 1.0)

    def raw(self, xs, sample, fixed: tuple[float, float] | None = None) -> np.ndarray:
        """(positions, rotations) mean squares at each offset, (inf, inf) where too few pairs."""
        with_rot = 1 in self.terms
        return np.array([self.cost.residuals(x, sample, fixed, with_rot)[:2] for x in xs]).reshape(-1, 2)

    def scan(self, xs: np.ndarray, sample, fixed: tuple[float, float] | None = None) -> np.ndarray:
        """Objective at each offset, with floors reset to this scan's smallest residuals."""
        pr = self.raw(xs, sample, fixed)
        if fixed is not None and not np.isfinite(pr).any():  # the bracket pokes past the data
            pr = self.raw(xs, sample)
        finite = np.isfinite(pr[:, 0])
        if finite.any():
            low = pr[finite].min(axis=0)
            self.floors = (max(low[0], FLOOR_POS_M2), max(low[1], FLOOR_ROT))
        return self.combine(pr)

    def combine(self, pr: np.ndarray) -> np.ndarray:
        return sum(pr[:, t] / self.floors[t] for t in self.terms) / len(self.terms)


def _localise(obj: _Objective, x: float, h: float, coarse) -> tuple[float, float]:
    """Grids of offsets around ``x`` on the coarse sample, 5x finer each time, until the step is below
    ``FULL_DATA_STEP_S``: (best offset, step)."""
    while h > FULL_DATA_STEP_S:
        xs = x + h * np.arange(-GRID_HALF, GRID_HALF + 1)
        x = float(xs[int(np.argmin(obj.scan(xs, coarse, (xs[0], xs[-1]))))])
        h /= 5.0
    return x, h


def _refine(obj: _Objective, x: float, h: float, full) -> float:
    """A grid on all poses, then a bounded scalar search between its best point's neighbours (stage 3)."""
    xs = x + h * np.arange(-GRID_HALF, GRID_HALF + 1)
    x = float(xs[int(np.argmin(obj.scan(xs, full, (xs[0], xs[-1]))))])
    span = (xs[0], xs[-1])  # the pairs of the last grid, so the search compares like with like

    def f(v: float) -> float:
        j = obj.combine(obj.raw([v], full, span))[0]
        return float(j) if np.isfinite(j) else 1e300

    xm, fm = minimize_bounded(f, x - h, x + h, xatol=FINE_STEP_S)
    return xm if fm <= f(x) else x


def _precision(obj: _Objective, term: int, x: float, full) -> float | None:
    """1-sigma of one term's offset: the spread of the cost's slope over ``PRECISION_BLOCKS`` consecutive blocks
    of pairs (correlated residuals, such as drift, spread it) over the cost's curvature. None when flat."""
    span = (x - CURVATURE_S, x + CURVATURE_S)
    j = obj.raw([x, *span], full, span)[:, term]
    n = obj.cost.residuals(x, full, span)[2]
    slopes = obj.cost.slopes(x, full, span, CURVATURE_S)
    curv = n * (j[1] + j[2] - 2 * j[0]) / CURVATURE_S**2  # of the sum of squares
    if slopes is None or not (curv > 0 and np.isfinite(curv)):
        return None
    g = np.array([b.sum() for b in np.array_split(slopes[term], PRECISION_BLOCKS)])
    sandwich = float(np.sqrt(len(g) / (len(g) - 1) * np.sum((g - g.mean()) ** 2)) / curv)
    # white residuals of this size give at least this: the sandwich alone comes out far too small when the few
    # blocks that determine the offset have, at the optimum, nearly zero slope (a yaw at a steady rate is
    # matched as well by a world rotation as by a time shift, so only the blocks where the rate turns count)
    white = float(np.sqrt(2.0 * j[0] / (3.0 * curv)))
    return max(sandwich, white)


def _relative(v: np.ndarray) -> np.ndarray:
    """``v`` over its smallest finite value (kept as is when nothing is finite or the minimum is 0)."""
    finite = v[np.isfinite(v)]
    low = float(finite.min()) if finite.size else 0.0
    return v / low if low > 0 else v.copy()


def default_range_ns(ref: Trajectory, est: Trajectory) -> tuple[int, int]:
    """Offsets at which the time spans overlap by at least half the shorter one."""
    dur_r = int(ref.stamps_ns[-1] - ref.stamps_ns[0])
    dur_e = int(est.stamps_ns[-1] - est.stamps_ns[0])
    half = min(dur_r, dur_e) // 2
    return int(ref.stamps_ns[0] - est.stamps_ns[-1]) + half, int(ref.stamps_ns[-1] - est.stamps_ns[0]) - half


def _no_match(ref: Trajectory, est: Trajectory, lo_ns: int, hi_ns: int, max_diff_ns: int) -> InputError:
    a = int(ref.stamps_ns[0] - est.stamps_ns[-1]) - max_diff_ns
    b = int(ref.stamps_ns[-1] - est.stamps_ns[0]) + max_diff_ns
    lo_d, hi_d = default_range_ns(ref, est)
    mid = (lo_d + hi_d) / 2e9
    return InputError(
        f"--estimate-offset: no offset in {lo_ns / 1e9:.9g}..{hi_ns / 1e9:.9g} s pairs any stamp of {est.name} with "
        f"one of {ref.name} within --t-max-diff {max_diff_ns / 1e9:g} s; offsets in {a / 1e9:.9g}..{b / 1e9:.9g} s "
        f"overlap their time ranges (the midpoints meet at {mid:.9g} s): widen --offset-range"
    )


def estimate_offset(ref: Trajectory, est: Trajectory, max_diff_ns: int = 10_000_000, align: str = "se3",
                    range_ns: tuple[int, int] | None = None, rotations: bool = True) -> OffsetEstimate:
    """The constant offset (ns, added to ``est``'s stamps) that best pairs ``est`` with ``ref`` (module doc).

    ``rotations``: use the orientations too (False when either trajectory is position-only).
    """
    if align not in COST_ALIGNMENT:
        raise InputError(f"unknown alignment '{align}' (choose from {', '.join(COST_ALIGNMENT)})")
    for t in (ref, est):
        if len(t) < 2:
            raise InputError(f"--estimate-offset: {t.name} has {len(t)} pose; need at least two")
    lo_ns, hi_ns = range_ns if range_ns is not None else default_range_ns(ref, est)
    if not lo_ns < hi_ns:
        raise InputError(f"--estimate-offset: empty search range {lo_ns / 1e9:.9g}..{hi_ns / 1e9:.9g} s")
    cost = OffsetCost(ref, est, COST_ALIGNMENT[align], rotations)
    x_lo, x_hi = cost.x_s(lo_ns), cost.x_s(hi_ns)
    max_diff_s = max_diff_ns / 1e9
    step = max(max_diff_s, (x_hi - x_lo) / MATCH_GRID_MAX, 1e-6)
    grid = np.append(np.arange(x_lo, x_hi, step), x_hi)
    counts, sampled = cost.matches(grid, max_diff_s, MATCH_SAMPLE)
    best = int(counts.max())
    if best == 0:
        raise _no_match(ref, est, lo_ns, hi_ns, max_diff_ns)
    cand = grid[counts >= max(1, int(np.ceil(NEAR_BEST * best)))]
    cand = cand[even_indices(len(cand), COARSE_CANDIDATES)]
    coarse, full = cost.subset(COARSE_SAMPLE), cost.subset(FINE_SAMPLE)
    terms = (0, 1) if rotations else (0,)
    obj = _Objective(cost, terms)
    j = obj.scan(cand, coarse)
    if not np.isfinite(j).any():
        raise InputError(f"--estimate-offset: no offset in {lo_ns / 1e9:.9g}..{hi_ns / 1e9:.9g} s leaves enough "
                         f"overlapping poses of {est.name} and {ref.name} to align")
    curve_x, curve_j = cand[np.isfinite(j)], j[np.isfinite(j)]
    x_coarse = float(cand[int(np.argmin(j))])
    h = max(step, float(np.median(np.diff(cand))) if len(cand) > 1 else step) / 2
    x_near, h = _localise(obj, x_coarse, h, coarse)
    found = {}
    for term in terms:
        single = _Objective(cost, (term,))
        x = _refine(single, x_near, h, full)
        found[_TERMS[term]] = (x, _precision(single, term, x, full), single)
    name = min(found, key=lambda k: found[k][1] if found[k][1] is not None else np.inf)
    x_best, precision, single = found[name]
    note = None
    if len(found) == 2 and all(v[1] is not None for v in found.values()):
        (xa, sa, _), (xb, sb, _) = found.values()
        if abs(xa - xb) > DISAGREE_SIGMAS * np.hypot(sa, sb):
            note = (f"positions put the offset at {cost.delta_ns(found['positions'][0]) / 1e9:+.6f} s and rotations at "
                    f"{cost.delta_ns(found['rotations'][0]) / 1e9:+.6f} s, further apart than their precision "
                    f"(drift, or different body frames?); the sharper {name} decide")
    probe = (x_best - SENSITIVITY_S, x_best + SENSITIVITY_S)
    fixed = probe if np.isfinite(cost.residuals(x_best, full, probe)[0]) else None
    raw = single.raw([x_best, *probe], full, fixed)
    term = 0 if name == "positions" else 1
    rise = (raw[1, term] + raw[2, term]) / (2 * max(raw[0, term], FLOOR_POS_M2 if term == 0 else FLOOR_ROT)) - 1.0
    if np.isfinite(rise) and not (rise > 0 and precision is not None and precision < FLAT_PRECISION_S):
        sigma = "" if precision is None else f" (1-sigma {1e3 * precision:.3g} ms)"
        note = (f"the aligned error changes by only {100 * rise:.2g} % {SENSITIVITY_S:g} s either side of the "
                f"offset{sigma}: the motion barely determines it")
        precision = None
    zoom = x_best + ZOOM_S * np.linspace(-1.0, 1.0, 2 * ZOOM_HALF + 1)
    zoom_j = single.combine(single.raw(zoom, full))
    return OffsetEstimate(
        offset_ns=cost.delta_ns(x_best), range_ns=(int(lo_ns), int(hi_ns)), alignment=cost.align,
        rmse_m=float(np.sqrt(raw[0, 0])), rot_rmse_deg=float(np.rad2deg(np.sqrt(raw[0, 1] / 2.0))) if rotations else None,
        best_matches=best, sampled=sampled, rise=float(rise) if np.isfinite(rise) else None, precision_s=precision,
        decided_by=name, by_term={k: {"offset_s": cost.delta_ns(v[0]) / 1e9, "precision_s": v[1]} for k, v in found.items()},
        note=note, grid_ns=np.array([cost.delta_ns(x) for x in grid], dtype=np.int64), grid_matches=counts,
        curve_ns=np.array([cost.delta_ns(x) for x in curve_x], dtype=np.int64), curve_cost=_relative(curve_j),
        zoom_ns=np.array([cost.delta_ns(x) for x in zoom], dtype=np.int64), zoom_cost=_relative(zoom_j),
    )
