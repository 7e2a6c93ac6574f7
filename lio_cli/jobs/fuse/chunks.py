"""A log fused in overlapping time chunks (``memory.plan`` sized them) and stitched into one trajectory.

A chunk is fused alone over its span plus ``overlap`` on each side, so every kept instant has data before and
after it, from the state the chunk before estimated at its first stamp (``core.fuse.pieces``: attitude,
velocity, biases; the planar and 3D filters and the factor graph hand it over, the complementary filter does not:
its chunks find their start again). Each chunk is carried into the first one's world (``stitch``: without GPS
joined onto the chunk before; with GPS placed on the fixes, its world being theirs). Poses left of the seam come
from chunk k-1, the rest from chunk k (faded from one to the other about the seam where both are on the fixes).
Covariances and velocities are rotated along; each chunk's covariance is relative to its own start (its position
was pinned there). Updates and notes are counted over the kept spans (``stitch.merge_reports``).

Decisions on the whole log are taken once and given to every chunk (``whole_log_options``: the estimator, the
wheels' yaw weighing), and so are those on the GPS fixes (``judge_gps``): which fixes lie in multipath jumps (a
chunk sees no jump that opened before it, and takes the track's return for one), and whether the fixes agree
with the motion sources (``core.fuse.agreement``): with GPS beside IMU + wheels the chunks fuse the fixes without
testing them, the log is fused in chunks without GPS too where the whole log asks for the test, and the two
stitched trajectories are judged on the whole log.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import replace

import numpy as np

from ...core.fuse import FuseInputs, FuseOptions, FuseResult, fuse, judge_gps
from ...core.fuse import rest
from ...core.fuse.agreement import WHOLE_LOG_NOTES, GpsJudge
from ...errors import InputError, LioError
from .memory import MemoryPlan
from .stitch import (align_onto, carried, cross_fade, enu_shift, from_enu, kept_shares, merge_reports,
                     merge_wheel_checks, taken)

Step = Callable[[int, int], None]


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


def fuse_chunked(inputs: FuseInputs, options: FuseOptions, memory: MemoryPlan,
                 step: Step | None = None) -> tuple[FuseResult, list[dict]]:
    """Fuse chunk by chunk (see the module docstring); one chunk is a plain ``fuse`` call."""
    if len(memory.chunks) == 1:
        res = fuse(inputs, options)
        if step:
            step(1, 1)
        return res, []
    judge = judge_gps(inputs, options)
    if judge is None:
        return _fuse_pieces(inputs, options, memory, step)
    if not judge.tests:
        return _with_gps(judge, *_fuse_pieces(inputs, replace(options, gps_jumps_ns=judge.jumps_ns), memory, step))
    half = None if step is None else (lambda k, n: step(k, 2 * n))
    fused, infos = _with_gps(judge, *_fuse_pieces(
        inputs, replace(options, test_gps_shape=False, gps_jumps_ns=judge.jumps_ns), memory, half))
    wanted, asked = judge.asks(fused)
    free = None
    if wanted:
        rest = None if step is None else (lambda k, n: step(n + k, 2 * n))
        use = None if options.use is None else {k: set(v) for k, v in options.use.items() if k != "gps"}
        try:
            free, free_infos = _fuse_pieces(replace(inputs, gps=None), replace(options, use=use), memory, rest)
        except LioError:  # the sources without GPS do not make a run: the GPS-fused one stands
            free = None
    if step:
        step(1, 1)
    if free is None:
        return fused, infos
    result = judge.judge(fused, free, asked)
    return result, (free_infos if result.info.get("gps_shape", {}).get("kept", "").startswith("motion") else infos)


def _with_gps(judge: GpsJudge, result: FuseResult, infos: list[dict]) -> tuple[FuseResult, list[dict]]:
    """The stitched result with the whole log's own GPS counts (jumps, dropouts: a piece sees a part of one)."""
    if "gps" in result.reports:
        notes = result.reports["gps"].notes
        for k in WHOLE_LOG_NOTES:
            notes.pop(k, None)
        notes.update(judge.counts)
    return result, infos


def _fuse_pieces(inputs: FuseInputs, options: FuseOptions, memory: MemoryPlan,
                 step: Step | None) -> tuple[FuseResult, list[dict]]:
    """Every chunk fused and stitched (``stitch``)."""
    ov, n = memory.overlap_ns, len(memory.chunks)
    kept: list[FuseResult] = []
    shares: list[dict[str, float]] = []
    infos: list[dict] = []
    prev: FuseResult | None = None
    prev_placed = False
    enu = None  # (4,4) the fixes' ENU frame into the stitched world (from the first chunk placed on them)
    start = None  # the state the chunk before handed over at this chunk's first stamp
    for k, (a, b) in enumerate(memory.chunks):
        nxt = memory.chunks[k + 1][0] - ov if k + 1 < n else None
        piece = slice_inputs(inputs, a - ov, b + ov)
        try:
            res = fuse(piece, replace(options, start=start, handover_ns=nxt))
        except InputError as err:  # a chunk inside a long gap of every source holds nothing to fuse
            if "no usable sample" not in str(err) and "no motion source" not in str(err):
                raise
            infos.append({"span_ns": [a, b], "skipped": str(err)})
            start = None
            continue
        start = res.info.pop("handover", None)
        placed, joined, A = res.origin_enu_xy_m is not None, True, np.eye(4)
        if prev is not None:
            A, joined = (enu_shift(prev, res, enu @ from_enu(res.origin_enu_xy_m), a), True) \
                if placed and enu is not None else align_onto(prev, res, a)
            res = carried(res, A)
        if placed and enu is None:
            enu = A @ np.linalg.inv(from_enu(res.origin_enu_xy_m))
        last = k == n - 1
        keep = (res.stamps_ns >= a) & ((res.stamps_ns <= b) if last else (res.stamps_ns < b))
        if kept and len(kept[-1]):  # never repeat a stamp the previous chunk already gave
            keep &= res.stamps_ns > kept[-1].stamps_ns[-1]
        cur = taken(res, keep)
        if placed and kept:  # on the fixes: faded from the chunk before (on them too, or joined onto one)
            kept[-1], cur = cross_fade(kept[-1], cur, prev, res, a, ov // 2)
        kept.append(cur)
        shares.append(kept_shares({s: v.stamps_ns for s, v in piece.present().items()}, (a, b, last)))
        infos.append({"span_ns": [a, b], "poses": int(np.count_nonzero(keep)), "joined_on_overlap": joined,
                      "placed_on_fixes": placed, "start": res.info.get("start"),
                      "wheel_check": res.info.get("wheel_check"), "rest": res.info.get("rest"),
                      "grade": (res.info.get("level") or {}).get("grade")})
        prev, prev_placed = res, placed
        if step:
            step(k + 1, n)
    if not kept:
        raise InputError("no usable sample in any motion source")
    return _merged(inputs, kept, shares, infos), infos


def _merged(inputs: FuseInputs, kept: list[FuseResult], shares: list[dict[str, float]], infos: list[dict]
            ) -> FuseResult:
    """The kept spans as one result: the first chunk's information, the counters of the kept spans, every
    chunk's notes once."""
    first = kept[0]
    merged = replace(first, stamps_ns=np.concatenate([r.stamps_ns for r in kept]),
                     poses=np.concatenate([r.poses for r in kept]),
                     covariances=None if first.covariances is None else np.concatenate([r.covariances for r in kept]),
                     velocities_mps=None if first.velocities_mps is None else np.concatenate(
                         [r.velocities_mps for r in kept]),
                     reports=merge_reports([r.reports for r in kept], shares), info=dict(first.info))
    for src, series in inputs.present().items():  # the chunks' overlaps received each message twice
        if src in merged.reports:
            merged.reports[src].received = len(series)
    if len(kept) > 1 and any(i.get("wheel_check") for i in infos):
        merged.info["wheel_check"] = merge_wheel_checks([i.get("wheel_check") for i in infos])
    grades = [i.get("grade") for i in infos if i.get("grade") is not None]
    if len(kept) > 1 and grades and "level" in merged.info:  # each chunk followed its own grade, or none
        k = sum(bool(g["followed"]) for g in grades)
        merged.info["level"] = {**merged.info["level"], "grade": {"followed": k > 0, "followed_chunks": k,
                                                                  "chunks": len(grades)}}
    if len(kept) > 1:  # what any chunk said (a gap or a stale fix lies in one of them), each once
        merged.info["rest"] = rest.summary(rest.pieces_joined([(i.get("rest"), *i["span_ns"]) for i in infos]))
        merged.info["notes"] = list(dict.fromkeys(n for r in kept for n in r.info.get("notes", [])))
        if any(r.info.get("outputs_in_gyro_gaps") for r in kept) and inputs.imu is not None:  # overlaps: once
            merged.info["outputs_in_gyro_gaps"] = int(np.count_nonzero(~np.isin(merged.stamps_ns,
                                                                                inputs.imu.stamps_ns)))
    return merged


__all__ = ["fuse_chunked", "slice_inputs"]
