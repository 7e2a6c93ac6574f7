"""Bounded memory for ``lio fuse``: estimate what the estimation core will hold, and when it exceeds the budget
fuse the log in overlapping time chunks and stitch them.

The core keeps per filter instant ("knot": an output or an update) about ``65 n^2`` bytes when smoothing with
the RTS pass (it needs predicted and filtered state and covariance and the transition of every knot; n = 15 for
the IMU-driven EKF, 21 with odometry increments), a few kB for the planar RTS pass (2.8 kB measured on a 60 s
drive, 5.2 kB with odometry increments' clone), and about 1.6 kB per IMU sample, output and update when only
filtering or when the factor graph smooths (its filter pass keeps no RTS record and the graph solves one chunk of
keyframes at a time, ``core.fuse.graph.solve``). An hour at 200 Hz with smoothing would be ~10 GB; chunked, it is
the budget. When chunks cannot bring it under the budget (a span of at most two chunks, or the shortest chunk alone
over it: e.g. ``--rate`` far above the IMU's rate, where every output is a knot) the run is refused before fusing,
naming the estimate, the budget and what to change.

The chunks are fused and stitched by ``chunks``.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ...core.fuse import FuseInputs, FuseOptions, graph_smooths
from ...errors import ConfigError

SMOOTH_BYTES_PER_N2 = 65
PLANAR_SMOOTH_BYTES = 3_000
PLANAR_DELTA_SMOOTH_BYTES = 5_500  # with odometry increments: 9 states instead of 6
FILTER_BYTES = 1_600
MIN_CHUNK_S = 30.0
MAX_OVERLAP_S = 10.0


@dataclass(frozen=True)
class MemoryPlan:
    knots: int
    bytes_per_knot: int
    estimate_mb: float
    budget_mb: float
    chunks: list[tuple[int, int]]  # kept spans [a, b) in ns (the last one closed)
    overlap_ns: int

    def to_dict(self) -> dict:
        return {"knots": self.knots, "bytes_per_knot": self.bytes_per_knot, "estimate_mb": round(self.estimate_mb, 1),
                "budget_mb": self.budget_mb, "chunks": len(self.chunks), "overlap_s": self.overlap_ns * 1e-9,
                "chunk_spans_s": [round((b - a) * 1e-9, 3) for a, b in self.chunks]}


def _span(inputs: FuseInputs) -> tuple[int, int]:
    st = [s.stamps_ns for k, s in inputs.present().items() if k != "gps"]
    lo = min(int(np.min(s)) for s in st)
    hi = max(int(np.max(s)) for s in st)
    return lo, hi


def knot_count(inputs: FuseInputs, use: dict[str, list[str]], rate_hz: float | None) -> int:
    """An upper bound of the filter instants: outputs (and IMU samples) plus updates."""
    lo, hi = _span(inputs)
    imu = len(inputs.imu) if inputs.imu is not None and "imu" in use else 0
    outputs = int((hi - lo) * 1e-9 * rate_hz) + 1 if rate_hz else (imu or sum(
        len(getattr(inputs, s)) for s in ("wheel", "odom") if getattr(inputs, s) is not None and s in use))
    updates = sum(len(getattr(inputs, s)) for s in ("wheel", "odom", "gps") if getattr(inputs, s) is not None and s in use)
    if imu and "orientation" in use.get("imu", ()) and inputs.imu.orientation_valid is not None:
        updates += int(np.count_nonzero(inputs.imu.orientation_valid))
    return max(outputs, imu) + updates


def bytes_per_knot(options: FuseOptions, use: dict[str, list[str]]) -> int:
    if not options.smooth or graph_smooths(use, options.estimator):  # the filter, or the graph's filter pass
        return FILTER_BYTES
    if options.estimator == "planar":
        return PLANAR_DELTA_SMOOTH_BYTES if "delta" in use.get("odom", ()) else PLANAR_SMOOTH_BYTES
    n = (15 if "accel" in use.get("imu", ()) else 12) + (6 if "delta" in use.get("odom", ()) else 0)
    return SMOOTH_BYTES_PER_N2 * n * n


def plan(inputs: FuseInputs, options: FuseOptions, use: dict[str, list[str]], budget_mb: float) -> MemoryPlan:
    """One chunk when the estimate fits the budget; else equal chunks that each fit (at least MIN_CHUNK_S)."""
    lo, hi = _span(inputs)
    knots = knot_count(inputs, use, options.rate_hz)
    per = bytes_per_knot(options, use)
    est = knots * per / 1e6
    if est <= budget_mb:
        return MemoryPlan(knots, per, est, budget_mb, [(lo, hi)], 0)
    span_s = (hi - lo) * 1e-9
    if span_s <= 2 * MIN_CHUNK_S:
        raise _over_budget(est, budget_mb, est, f"a {span_s:.3g} s log is too short to fuse in chunks "
                           f"(that needs over {2 * MIN_CHUNK_S:g} s)", inputs, options, use)
    knots_per_s = knots / span_s
    overlap_s = MAX_OVERLAP_S
    chunk_s = max(MIN_CHUNK_S, budget_mb * 1e6 / per / knots_per_s - 2 * overlap_s)
    overlap_s = min(MAX_OVERLAP_S, chunk_s / 3)
    chunk_mb = knots_per_s * (chunk_s + 2 * overlap_s) * per / 1e6
    if chunk_mb > budget_mb * 1.001:
        raise _over_budget(est, budget_mb, chunk_mb, f"even the shortest chunk ({chunk_s:g} s plus {overlap_s:g} s "
                           f"of overlap each side) needs {int(np.ceil(chunk_mb))} MB", inputs, options, use)
    n = int(np.ceil(span_s / chunk_s))
    edges = np.linspace(lo, hi, n + 1).round().astype(np.int64)
    return MemoryPlan(knots, per, est, budget_mb, [(int(a), int(b)) for a, b in zip(edges[:-1], edges[1:])],
                      int(overlap_s * 1e9))


def _fastest_source(inputs: FuseInputs, use: dict[str, list[str]]) -> tuple[str, float]:
    """The motion source in use with the most samples per second, and that rate (Hz)."""
    best = ("", 0.0)
    for name in ("imu", "wheel", "odom"):
        s = getattr(inputs, name)
        if s is None or name not in use or len(s) < 2:
            continue
        hz = (len(s) - 1) / max((int(s.stamps_ns[-1]) - int(s.stamps_ns[0])) * 1e-9, 1e-9)
        best = max(best, (name, hz), key=lambda b: b[1])
    return best


def _over_budget(est_mb: float, budget_mb: float, need_mb: float, why: str, inputs: FuseInputs,
                 options: FuseOptions, use: dict[str, list[str]]) -> ConfigError:
    """The refusal of a run the memory budget cannot hold, with what to change (before any fusing)."""
    raise_to = f"raise --max-memory to {int(np.ceil(need_mb))} (MB) or more"
    src, hz = _fastest_source(inputs, use)
    src = {"imu": "IMU", "wheel": "wheel odometry", "odom": "odometry"}.get(src, src)
    rate = options.rate_hz
    if rate and hz and rate > hz:
        advice = (f"--rate {rate:g} Hz is {rate / hz:.0f} times the {src} rate of {hz:.0f} Hz, and poses between "
                  f"{src} samples carry no measurement of their own: lower --rate to {hz:.0f} Hz or less, or {raise_to}")
    else:
        rts = bytes_per_knot(options, use) > FILTER_BYTES  # the RTS pass's record is what --no-smooth saves
        advice = ("fuse --no-smooth or " if rts else "") + raise_to  # every IMU sample is a knot anyway
    return ConfigError(f"fusing needs about {est_mb:.0f} MB, over the memory budget of {budget_mb:g} MB "
                       f"(--max-memory), and {why}: {advice}")


__all__ = ["MemoryPlan", "bytes_per_knot", "knot_count", "plan"]
