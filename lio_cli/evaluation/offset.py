"""Estimating a constant time offset between an estimate's and a reference's stamps.

The offset ``delta`` is what ``--t-offset`` means: seconds added to the estimate's stamps to put them on the
reference's clock. Three stages, each on what the previous one kept:

1. Matches: over the search range (default: every offset at which the two time spans overlap by at least
   half the shorter one), count on a grid how many stamps of the sparser trajectory find a stamp of the
   denser one within ``max_diff`` (a sample of at most ``MATCH_SAMPLE`` stamps; grid step ``max_diff``, at
   most ``MATCH_GRID_MAX`` points). Offsets reaching ``NEAR_BEST`` of the best count are candidates.
2. Coarse error: at up to ``COARSE_CANDIDATES`` candidates, the aligned error: the denser trajectory's
   positions are interpolated (linearly) at the sparser one's shifted stamps, the pairs aligned as asked
   (``COST_ALIGNMENT``) and the translation RMSE taken. The cost is continuous in the offset.
3. Refinement: grids of 21 offsets around the best one, each 5x finer, down to ``FINE_STEP_S``, on all
   poses (up to ``FINE_SAMPLE``) once the step is below ``FULL_DATA_STEP_S``; a parabola through the last
   three points gives the sub-step minimum.

Cost is O(range / max_diff * MATCH_SAMPLE + N): it does not grow with how far apart two clocks are.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from ..errors import InputError
from .alignment import posyaw, umeyama
from .association import Trajectory

# The alignment the cost uses for each --align: origin fits one pose and scale no rotation, so the error
# after them mixes misalignment into the time offset; se3 and sim3 stand in for them.
COST_ALIGNMENT = {"none": "none", "se3": "se3", "sim3": "sim3", "scale": "sim3", "origin": "se3", "posyaw": "posyaw"}
MATCH_GRID_MAX = 4000
MATCH_SAMPLE = 250
NEAR_BEST = 0.9
COARSE_CANDIDATES = 200
COARSE_SAMPLE = 1000
FINE_SAMPLE = 5000
FULL_DATA_STEP_S = 5e-3
FINE_STEP_S = 2e-5
GRID_HALF = 10  # refinement grids hold 2 * GRID_HALF + 1 offsets
SENSITIVITY_S = 0.1  # the cost is probed this far either side of the estimate to judge how well it is defined
FLAT_RISE = 0.05  # a rise below this fraction of the minimum (or FLAT_RISE_M) marks a poorly defined offset
FLAT_RISE_M = 1e-4
ZOOM_S = 0.25  # the plotted close-up covers this far either side of the estimate
ZOOM_HALF = 25
NOISE_SAMPLE = 5000  # poses used to judge which trajectory is smoother
_CHI2_3_MEDIAN_OVER_3 = 2.365974 / 3.0  # median of a chi-square with 3 dof, per axis


@dataclass
class OffsetEstimate:
    """The offset found for one estimate, how it was found, and the curves behind it (for plots)."""

    offset_ns: int
    range_ns: tuple[int, int]
    alignment: str  # the alignment of the cost
    rmse_m: float  # aligned translation RMSE of interpolated pairs at the offset
    best_matches: int  # stage 1: most sampled stamps paired at one offset
    sampled: int  # stage 1: stamps sampled
    rise_m: float | None  # mean cost increase SENSITIVITY_S either side of the offset (None: no pairs there)
    note: str | None = None  # set when the motion barely determines the offset
    grid_ns: np.ndarray = field(default_factory=lambda: np.zeros(0, np.int64), repr=False)
    grid_matches: np.ndarray = field(default_factory=lambda: np.zeros(0, np.int64), repr=False)
    curve_ns: np.ndarray = field(default_factory=lambda: np.zeros(0, np.int64), repr=False)
    curve_rmse_m: np.ndarray = field(default_factory=lambda: np.zeros(0), repr=False)
    zoom_ns: np.ndarray = field(default_factory=lambda: np.zeros(0, np.int64), repr=False)
    zoom_rmse_m: np.ndarray = field(default_factory=lambda: np.zeros(0), repr=False)

    @property
    def offset_s(self) -> float:
        return self.offset_ns / 1e9

    def summary(self) -> dict:
        return {"offset_s": self.offset_s, "search_range_s": [self.range_ns[0] / 1e9, self.range_ns[1] / 1e9],
                "cost_alignment": self.alignment, "rmse_m": self.rmse_m,
                "matches_sampled": {"best": self.best_matches, "of": self.sampled},
                "rise_m_at_0.1s": self.rise_m, "note": self.note}


def _even(n: int, k: int) -> np.ndarray:
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
    i = _even(n - 4, limit) + 2
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


def _tangents(t: np.ndarray, p: np.ndarray) -> np.ndarray:
    """Central-difference velocities (one-sided at the ends) for cubic Hermite interpolation."""
    m = np.empty_like(p)
    m[1:-1] = (p[2:] - p[:-2]) / (t[2:] - t[:-2])[:, None]
    m[0] = (p[1] - p[0]) / (t[1] - t[0])
    m[-1] = (p[-1] - p[-2]) / (t[-1] - t[-2])
    return m


class _Problem:
    """Both trajectories on one time axis: seconds since each first stamp, the estimate shifted by x.

    ``delta_ns = base_ns + x * 1e9``, where ``base_ns`` puts the two first stamps together; floats only ever
    hold relative seconds, so clocks 1e9 s apart lose nothing. Matching pairs the sparser trajectory's stamps
    with the denser one's (as association does). The cost interpolates the smoother trajectory (lower
    ``noise_level_m``) at the other's stamps, with a cubic: interpolating the noisier one would make the
    error depend on where its samples fall (noise averages out between samples), which biases the offset.
    """

    def __init__(self, ref: Trajectory, est: Trajectory, align: str) -> None:
        self.base_ns = int(ref.stamps_ns[0]) - int(est.stamps_ns[0])
        self.t_ref = (ref.stamps_ns - ref.stamps_ns[0]) / 1e9
        self.t_est = (est.stamps_ns - est.stamps_ns[0]) / 1e9
        self.p_ref, self.p_est = ref.positions, est.positions
        self.est_sparse = len(est) <= len(ref)
        noise_ref, noise_est = noise_level_m(self.t_ref, self.p_ref), noise_level_m(self.t_est, self.p_est)
        # est queried (ref interpolated) unless the reference is the noisier one; density decides a tie or NaN
        self.query_est = not noise_est < noise_ref if noise_ref == noise_ref and noise_est == noise_est else self.est_sparse
        t_d, p_d = (self.t_ref, self.p_ref) if self.query_est else (self.t_est, self.p_est)
        self.m_d = _tangents(t_d, p_d) if len(t_d) > 1 else np.zeros_like(p_d)
        self.align = COST_ALIGNMENT[align]
        self.need = 2 if self.align in ("none", "posyaw") else 3

    def delta_ns(self, x_s: float) -> int:
        return self.base_ns + int(round(x_s * 1e9))

    def x_s(self, delta_ns: int) -> float:
        return (int(delta_ns) - self.base_ns) / 1e9

    def _sides(self, query_est: bool):
        """(query times, positions, interpolated times, positions, sign): query + sign * x is the other's time."""
        if query_est:
            return self.t_est, self.p_est, self.t_ref, self.p_ref, 1.0
        return self.t_ref, self.p_ref, self.t_est, self.p_est, -1.0

    def matches(self, xs: np.ndarray, max_diff_s: float) -> tuple[np.ndarray, int]:
        """Sampled sparse stamps with a dense stamp within ``max_diff_s``, per offset; and the sample size."""
        t_s, _, t_d, _, sign = self._sides(self.est_sparse)
        sample = t_s[_even(len(t_s), MATCH_SAMPLE)]
        counts = np.zeros(len(xs), dtype=np.int64)
        rows = max(1, 2_000_000 // len(sample))
        for k in range(0, len(xs), rows):
            q = sample[None, :] + sign * xs[k:k + rows, None]
            j = np.clip(np.searchsorted(t_d, q), 1, len(t_d) - 1) if len(t_d) > 1 else np.zeros(q.shape, np.int64)
            gap = np.minimum(np.abs(t_d[j] - q), np.abs(t_d[np.maximum(j - 1, 0)] - q))
            counts[k:k + rows] = np.count_nonzero(gap <= max_diff_s, axis=1)
        return counts, len(sample)

    def subset(self, k: int) -> tuple[np.ndarray, np.ndarray]:
        """(times, positions) of at most ``k`` evenly spread stamps of the queried trajectory."""
        t_s, p_s = self._sides(self.query_est)[:2]
        idx = _even(len(t_s), k)
        return t_s[idx], np.ascontiguousarray(p_s[idx])

    def cost(self, x: float, sample: tuple[np.ndarray, np.ndarray], fixed: tuple[float, float] | None = None) -> float:
        """Aligned translation RMSE of the pairs at offset ``x`` (inf with too few pairs or a degenerate fit).

        ``fixed``: keep only the queried stamps that stay inside the other's span for every x in this interval,
        so a scan over it compares the same pairs.
        """
        _, _, t_d, p_d, sign = self._sides(self.query_est)
        t, p = sample
        lo, hi = (x, x) if fixed is None else fixed
        inside = np.ones(len(t), dtype=bool)
        for bound in (lo, hi):
            q = t + sign * bound
            inside &= (q >= t_d[0]) & (q <= t_d[-1])
        if np.count_nonzero(inside) < self.need:
            return float("inf")
        q = t[inside] + sign * x
        j = np.clip(np.searchsorted(t_d, q), 1, len(t_d) - 1)
        h = t_d[j] - t_d[j - 1]
        u = ((q - t_d[j - 1]) / h)[:, None]
        u2, u3 = u * u, u * u * u
        other = ((2 * u3 - 3 * u2 + 1) * p_d[j - 1] + (u3 - 2 * u2 + u) * h[:, None] * self.m_d[j - 1]
                 + (3 * u2 - 2 * u3) * p_d[j] + (u3 - u2) * h[:, None] * self.m_d[j])  # cubic Hermite
        src, dst = (p[inside], other) if self.query_est else (other, p[inside])  # the estimate is aligned
        try:
            if self.align == "none":
                res = dst - src
            elif self.align == "posyaw":
                R, tr = posyaw(src, dst)
                res = dst - (src @ R.T + tr)
            else:
                R, tr, s = umeyama(src, dst, with_scale=self.align == "sim3")
                res = dst - (s * src @ R.T + tr)
        except InputError:
            return float("inf")
        return float(np.sqrt(np.mean(np.sum(res**2, axis=1))))


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
                    range_ns: tuple[int, int] | None = None) -> OffsetEstimate:
    """The constant offset (ns, added to ``est``'s stamps) that best pairs ``est`` with ``ref`` (module doc)."""
    if align not in COST_ALIGNMENT:
        raise InputError(f"unknown alignment '{align}' (choose from {', '.join(COST_ALIGNMENT)})")
    for t in (ref, est):
        if len(t) < 2:
            raise InputError(f"--estimate-offset: {t.name} has {len(t)} pose; need at least two")
    lo_ns, hi_ns = range_ns if range_ns is not None else default_range_ns(ref, est)
    if not lo_ns < hi_ns:
        raise InputError(f"--estimate-offset: empty search range {lo_ns / 1e9:.9g}..{hi_ns / 1e9:.9g} s")
    pb = _Problem(ref, est, align)
    x_lo, x_hi = pb.x_s(lo_ns), pb.x_s(hi_ns)
    max_diff_s = max_diff_ns / 1e9
    step = max(max_diff_s, (x_hi - x_lo) / MATCH_GRID_MAX, 1e-6)
    grid = np.append(np.arange(x_lo, x_hi, step), x_hi)
    counts, sampled = pb.matches(grid, max_diff_s)
    best = int(counts.max())
    if best == 0:
        raise _no_match(ref, est, lo_ns, hi_ns, max_diff_ns)
    cand = grid[counts >= max(1, int(np.ceil(NEAR_BEST * best)))]
    cand = cand[_even(len(cand), COARSE_CANDIDATES)]
    idx = pb.subset(COARSE_SAMPLE)
    curve: dict[float, float] = {}
    costs = np.array([pb.cost(x, idx) for x in cand])
    curve.update(zip(cand.tolist(), costs.tolist()))
    if not np.isfinite(costs).any():
        raise InputError(f"--estimate-offset: no offset in {lo_ns / 1e9:.9g}..{hi_ns / 1e9:.9g} s leaves enough "
                         f"overlapping poses of {est.name} and {ref.name} to align")
    x_best = float(cand[int(np.argmin(costs))])
    h = max(step, float(np.median(np.diff(cand))) if len(cand) > 1 else step) / 2
    full = pb.subset(FINE_SAMPLE)
    while True:
        use = full if h <= FULL_DATA_STEP_S else idx
        xs = x_best + h * np.arange(-GRID_HALF, GRID_HALF + 1)
        span = (xs[0], xs[-1])
        c = np.array([pb.cost(x, use, span) for x in xs])
        if not np.isfinite(c).any():  # the bracket pokes past the data: score each offset on its own pairs
            c = np.array([pb.cost(x, use) for x in xs])
        if use is idx:  # the curve keeps costs of one sample only, so it reads as one function
            curve.update(zip(xs.tolist(), c.tolist()))
        k = int(np.argmin(c))
        x_best = float(xs[k])
        if h <= FINE_STEP_S:
            if 0 < k < len(xs) - 1 and np.isfinite(c[k - 1:k + 2]).all():
                den = c[k - 1] - 2 * c[k] + c[k + 1]
                if den > 0:
                    x_best -= 0.5 * h * (c[k + 1] - c[k - 1]) / den
            break
        h /= 5.0
    probe = (x_best - SENSITIVITY_S, x_best + SENSITIVITY_S)
    fixed = probe if np.isfinite(pb.cost(x_best, full, probe)) else None
    c0 = pb.cost(x_best, full, fixed)
    rise = (pb.cost(probe[0], full, fixed) + pb.cost(probe[1], full, fixed)) / 2 - c0
    note = None
    if np.isfinite(rise) and not rise > max(FLAT_RISE * c0, FLAT_RISE_M):
        note = (f"the aligned error changes by only {rise:.3g} m {SENSITIVITY_S:g} s either side of the offset: "
                f"the motion barely determines it")
    zoom = x_best + ZOOM_S * np.linspace(-1.0, 1.0, 2 * ZOOM_HALF + 1)
    zoom_cost = np.array([pb.cost(x, idx) for x in zoom])
    keys = sorted(k for k in curve if np.isfinite(curve[k]))
    return OffsetEstimate(
        offset_ns=pb.delta_ns(x_best), range_ns=(int(lo_ns), int(hi_ns)), alignment=pb.align, rmse_m=c0,
        best_matches=best, sampled=sampled, rise_m=float(rise) if np.isfinite(rise) else None, note=note,
        grid_ns=np.array([pb.delta_ns(x) for x in grid], dtype=np.int64), grid_matches=counts,
        curve_ns=np.array([pb.delta_ns(x) for x in keys], dtype=np.int64),
        curve_rmse_m=np.array([curve[k] for k in keys]),
        zoom_ns=np.array([pb.delta_ns(x) for x in zoom], dtype=np.int64), zoom_rmse_m=zoom_cost,
    )
