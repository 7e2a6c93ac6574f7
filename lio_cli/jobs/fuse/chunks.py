"""Bounded memory for ``lio fuse``: estimate what the estimation core will hold, and when it exceeds the budget
fuse the log in overlapping time chunks and stitch them.

The core keeps per filter instant ("knot": an output or an update) about ``65 n^2`` bytes when smoothing with
the RTS pass (it needs predicted and filtered state and covariance and the transition of every knot; n = 15 for
the IMU-driven EKF, 21 with odometry increments), a few kB for the planar RTS pass, and about 1.6 kB per IMU
sample, output and update when only filtering or when the factor graph smooths (its filter pass keeps no RTS
record and the graph solves one chunk of keyframes at a time, ``core.fuse.graph.solve``). An hour at 200 Hz with smoothing would be
~10 GB; chunked, it is the budget. When chunks cannot bring it under the budget (a span of at most two
chunks, or the shortest chunk alone over it: e.g. ``--rate`` far above the IMU's rate, where every output is
a knot) the run is refused before fusing, naming the estimate, the budget and what to change.

A chunk is fused alone over its span plus ``overlap`` on each side, so every kept instant has data before and
after it, from the state the chunk before estimated at its first stamp (``core.fuse.pieces``: attitude,
velocity, biases; the planar and 3D filters and the factor graph hand it over, the complementary filter does not:
its chunks find their start again). Each chunk's world starts at
its own origin; chunk k is carried onto chunk k-1 by a rotation about the vertical (mean yaw difference of the orientations over the overlap: gravity fixes the tilt in both) and
the translation that makes the two agree at the seam. Poses left of the seam come from chunk k-1, the rest
from chunk k. Covariances and velocities are rotated along; each chunk's covariance is relative to its own
start (its position was pinned there).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, replace

import numpy as np

from ...core.fuse import FuseInputs, FuseOptions, FuseResult, SourceReport, fuse, graph_smooths
from ...errors import ConfigError, InputError
from ...geometry import so3_exp_one, yaw_of

SMOOTH_BYTES_PER_N2 = 65
PLANAR_SMOOTH_BYTES = 3_000
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
        return PLANAR_SMOOTH_BYTES
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


def _slice(series, a: int, b: int):
    if series is None:
        return None
    keep = (series.stamps_ns >= a) & (series.stamps_ns <= b)
    out = {}
    for name, value in vars(series).items():
        if isinstance(value, np.ndarray) and value.shape[:1] == keep.shape and name not in ("T_base_imu", "antenna_m"):
            out[name] = value[keep]
        else:
            out[name] = value
    return type(series)(**out)


def slice_inputs(inputs: FuseInputs, a: int, b: int) -> FuseInputs:
    """The samples of every source stamped in [a, b]."""
    return FuseInputs(*(_slice(getattr(inputs, s), a, b) for s in ("imu", "wheel", "odom", "gps")))


def _yaw_rotation(psi: float) -> np.ndarray:
    return so3_exp_one(np.array([0.0, 0.0, psi]))


def align_onto(prev: FuseResult, nxt: FuseResult, seam_ns: int) -> tuple[np.ndarray, bool]:
    """``A`` (4,4: yaw and translation) carrying ``nxt``'s world onto ``prev``'s; False when they share no
    instant (then only the translation that joins prev's last pose to nxt's first)."""
    common, ip, inx = np.intersect1d(prev.stamps_ns, nxt.stamps_ns, return_indices=True)
    A = np.eye(4)
    if len(common) == 0:
        A[:3, 3] = prev.poses[-1, :3, 3] - nxt.poses[0, :3, 3]
        return A, False
    d = prev.poses[ip, :3, :3] @ np.transpose(nxt.poses[inx, :3, :3], (0, 2, 1))
    yaws = yaw_of(d)
    psi = float(np.arctan2(np.mean(np.sin(yaws)), np.mean(np.cos(yaws))))
    k = int(np.argmin(np.abs(common - seam_ns)))
    Rz = _yaw_rotation(psi)
    A[:3, :3] = Rz
    A[:3, 3] = prev.poses[ip[k], :3, 3] - Rz @ nxt.poses[inx[k], :3, 3]
    return A, True


def _transform(res: FuseResult, A: np.ndarray) -> FuseResult:
    poses = A @ res.poses
    vel = None if res.velocities_mps is None else res.velocities_mps @ A[:3, :3].T
    cov = res.covariances
    if cov is not None:
        J = np.eye(6)
        J[:3, :3] = A[:3, :3]
        cov = J @ cov @ J.T
    return replace(res, poses=poses, velocities_mps=vel, covariances=cov)


def _take(res: FuseResult, keep: np.ndarray) -> FuseResult:
    return replace(res, stamps_ns=res.stamps_ns[keep], poses=res.poses[keep],
                   covariances=None if res.covariances is None else res.covariances[keep],
                   velocities_mps=None if res.velocities_mps is None else res.velocities_mps[keep])


def merge_reports(parts: list[dict[str, SourceReport]]) -> dict[str, SourceReport]:
    out: dict[str, SourceReport] = {}
    for reports in parts:
        for src, r in reports.items():
            m = out.setdefault(src, SourceReport())
            m.received += r.received
            m.updates += r.updates
            m.predictions += r.predictions
            for k, v in r.rejected.items():
                m.reject(k, v)
            for k, v in r.notes.items():
                m.note(k, v)
            for kind, c in r.by_kind.items():
                t = m.by_kind.setdefault(kind, {"updates": 0, "outlier": 0})
                for key, v in c.items():
                    t[key] = t.get(key, 0) + v
    return out


def fuse_chunked(inputs: FuseInputs, options: FuseOptions, memory: MemoryPlan,
                 step: Callable[[int, int], None] | None = None) -> tuple[FuseResult, list[dict]]:
    """Fuse chunk by chunk (see the module docstring); one chunk is a plain ``fuse`` call."""
    if len(memory.chunks) == 1:
        res = fuse(inputs, options)
        if step:
            step(1, 1)
        return res, []
    ov, n = memory.overlap_ns, len(memory.chunks)
    kept: list[FuseResult] = []
    infos: list[dict] = []
    prev: FuseResult | None = None
    start = None  # the state the chunk before handed over at this chunk's first stamp
    for k, (a, b) in enumerate(memory.chunks):
        nxt = memory.chunks[k + 1][0] - ov if k + 1 < n else None
        try:
            res = fuse(slice_inputs(inputs, a - ov, b + ov), replace(options, start=start, handover_ns=nxt))
        except InputError as err:  # a chunk inside a long gap of every source holds nothing to fuse
            if "no usable sample" not in str(err) and "no motion source" not in str(err):
                raise
            infos.append({"span_ns": [a, b], "skipped": str(err)})
            start = None
            continue
        start = res.info.pop("handover", None)
        joined = True
        if prev is not None:
            A, joined = align_onto(prev, res, a)
            res = _transform(res, A)
        last = k == n - 1
        keep = (res.stamps_ns >= a) & ((res.stamps_ns <= b) if last else (res.stamps_ns < b))
        if kept and len(kept[-1]):  # never repeat a stamp the previous chunk already gave
            keep &= res.stamps_ns > kept[-1].stamps_ns[-1]
        kept.append(_take(res, keep))
        infos.append({"span_ns": [a, b], "poses": int(np.count_nonzero(keep)), "joined_on_overlap": joined,
                      "start": res.info.get("start"), "wheel_check": res.info.get("wheel_check")})
        prev = res
        if step:
            step(k + 1, n)
    if not kept:
        raise InputError("no usable sample in any motion source")
    first = kept[0]
    merged = replace(first, stamps_ns=np.concatenate([r.stamps_ns for r in kept]),
                     poses=np.concatenate([r.poses for r in kept]),
                     covariances=None if first.covariances is None else np.concatenate([r.covariances for r in kept]),
                     velocities_mps=None if first.velocities_mps is None else np.concatenate(
                         [r.velocities_mps for r in kept]),
                     reports=merge_reports([r.reports for r in kept]), info=dict(first.info))
    for src, series in inputs.present().items():  # the chunks' overlaps received each message twice
        if src in merged.reports:
            merged.reports[src].received = len(series)
    if len(kept) > 1 and any(i.get("wheel_check") for i in infos):
        merged.info["wheel_check"] = merge_wheel_checks([i.get("wheel_check") for i in infos])
    if len(kept) > 1:  # what any chunk said (a gap or a stale fix lies in one of them), each once
        merged.info["notes"] = list(dict.fromkeys(n for r in kept for n in r.info.get("notes", [])))
        if any(r.info.get("outputs_in_gyro_gaps") for r in kept) and inputs.imu is not None:  # overlaps: once
            merged.info["outputs_in_gyro_gaps"] = int(np.count_nonzero(~np.isin(merged.stamps_ns,
                                                                                inputs.imu.stamps_ns)))
    return merged, infos


def merge_wheel_checks(checks: list[dict | None]) -> dict:
    """One wheel check for a run fused in chunks: each chunk checked its own wheels (its windows relative to its
    start are in the chunk's own entry)."""
    done = [c for c in checks if c]
    # a chunk whose scale was not measured stopped before bridging: its windows were found, not bridged
    reached = [c for c in done if c.get("verified") or c.get("left_in")]
    left_in = sum(c.get("left_in", 0) for c in reached)
    slips, bridged = sum(c["slips"] for c in reached) - left_in, sum(c["bridged"] for c in done)
    scales = [c["scale"] if c["scale_applied"] else 1.0 for c in done]
    return {"slips": sum(c["slips"] for c in done), "windows_s": None, "scale": None, "scale_sigma": None,
            "bridged": bridged, "left_in": left_in, "verified": len(reached) == len(done) and not left_in,
            "scale_applied": any(c["scale_applied"] for c in done), "per_chunk_scale": scales,
            "why": f"checked per chunk ({len(done)} of {len(checks)}): {slips} slip(s) bridged by the IMU"
                   + (f", {left_in} left in" if left_in else "") + ", wheel scale "
                   + ", ".join(f"{v:.4f}" for v in scales)}


__all__ = ["MemoryPlan", "align_onto", "fuse_chunked", "knot_count", "merge_reports", "merge_wheel_checks", "plan", "slice_inputs"]
