"""The chunks of a log fused in pieces (``chunks``) made one trajectory: each carried into the first chunk's world,
the seams joined, the counters merged.

A chunk fused without GPS has a world of its own: ``align_onto`` carries it onto the chunk before by a rotation
about the vertical (mean yaw difference of the orientations over the overlap: gravity fixes the tilt in both) and
the translation that makes the two agree at the seam. A chunk that fused GPS is already in the fixes' ENU world,
but for its position (every run's first pose is put at the origin, ``anchor_to_origin``; where it lay is
``FuseResult.origin_enu_xy_m``): it is put back there (``from_enu``), never turned. Joined onto the chunk before
instead, it would carry that chunk's heading and position errors on, and lose its own placement on the fixes.
Its height is joined at the seam (``enu_shift``). Two such chunks differ where they overlap by what each made of
its own data; ``cross_fade`` passes from one to the other over the middle half of the overlap, so the trajectory
does not jump at the seam.
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from ...core.fuse import FuseResult, SourceReport
from ...geometry import interpolate_poses, so3_exp, so3_exp_one, so3_log, yaw_of

PER_CHUNK_NOTES = ("anchor",)  # notes each chunk makes once whatever its span (it ties its own world)


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
    Rz = so3_exp_one(np.array([0.0, 0.0, psi]))
    A[:3, :3] = Rz
    A[:3, 3] = prev.poses[ip[k], :3, 3] - Rz @ nxt.poses[inx[k], :3, 3]
    return A, True


def enu_shift(prev: FuseResult, nxt: FuseResult, A: np.ndarray, seam_ns: int) -> np.ndarray:
    """``A`` (4,4: placing ``nxt`` by where it lies on the fixes) with ``nxt``'s height joined onto ``prev``'s at
    the seam (the instant they share nearest to ``seam_ns``; none shared: prev's last and nxt's first)."""
    A = A.copy()
    common, ip, inx = np.intersect1d(prev.stamps_ns, nxt.stamps_ns, return_indices=True)
    i, j = -1, 0
    if len(common):
        k = int(np.argmin(np.abs(common - seam_ns)))
        i, j = ip[k], inx[k]
    A[2, 3] += prev.poses[i, 2, 3] - (A @ nxt.poses[j])[2, 3]
    return A


def from_enu(origin_enu_xy_m: np.ndarray) -> np.ndarray:
    """(4,4) the translation taking a result whose first pose lies at ``origin_enu_xy_m`` (``FuseResult``) into
    the fixes' ENU frame, horizontally."""
    T = np.eye(4)
    T[:2, 3] = origin_enu_xy_m
    return T


def cross_fade(before: FuseResult, after: FuseResult, prev: FuseResult, nxt: FuseResult, seam_ns: int,
               half_ns: int) -> tuple[FuseResult, FuseResult]:
    """The kept poses either side of the seam (``before``: the end of ``prev``'s, ``after``: the start of
    ``nxt``'s), passing from ``prev`` to ``nxt`` over ``seam_ns +- half_ns``: positions and velocities weighed
    linearly, orientations along the geodesic. Unchanged where the two chunks do not both cover that window."""
    lo, hi = seam_ns - half_ns, seam_ns + half_ns
    if half_ns <= 0 or len(prev) < 2 or len(nxt) < 2 or prev.stamps_ns[-1] < hi or nxt.stamps_ns[0] > lo:
        return before, after
    return _faded(before, nxt, lo, hi, own_first=True), _faded(after, prev, lo, hi, own_first=False)


def _faded(res: FuseResult, other: FuseResult, lo: int, hi: int, own_first: bool) -> FuseResult:
    """``res`` with its poses in [lo, hi] blended with ``other``'s: towards ``other`` as time goes on when
    ``own_first``, else from it."""
    sel = np.flatnonzero((res.stamps_ns >= lo) & (res.stamps_ns <= hi))
    if not len(sel):
        return res
    t = res.stamps_ns[sel]
    w = ((t - lo) / float(hi - lo))[:, None]  # the later chunk's share
    own, theirs = res.poses[sel], interpolate_poses(other.stamps_ns, other.poses, t)
    a, b = (own, theirs) if own_first else (theirs, own)
    poses = res.poses.copy()
    rel = np.einsum("nji,njk->nik", a[:, :3, :3], b[:, :3, :3])
    poses[sel, :3, :3] = a[:, :3, :3] @ so3_exp(so3_log(rel) * w)
    poses[sel, :3, 3] = (1.0 - w) * a[:, :3, 3] + w * b[:, :3, 3]
    vel = res.velocities_mps
    if vel is not None and other.velocities_mps is not None:
        vo = np.column_stack([np.interp(t, other.stamps_ns, other.velocities_mps[:, c]) for c in range(3)])
        va, vb = (vel[sel], vo) if own_first else (vo, vel[sel])
        vel = vel.copy()
        vel[sel] = (1.0 - w) * va + w * vb
    return replace(res, poses=poses, velocities_mps=vel)


def carried(res: FuseResult, A: np.ndarray) -> FuseResult:
    """``res`` moved by ``A`` (4,4), velocities and covariances turned along."""
    poses = A @ res.poses
    vel = None if res.velocities_mps is None else res.velocities_mps @ A[:3, :3].T
    cov = res.covariances
    if cov is not None:
        J = np.eye(6)
        J[:3, :3] = A[:3, :3]
        cov = J @ cov @ J.T
    return replace(res, poses=poses, velocities_mps=vel, covariances=cov)


def taken(res: FuseResult, keep: np.ndarray) -> FuseResult:
    """``res`` at the stamps ``keep`` selects."""
    return replace(res, stamps_ns=res.stamps_ns[keep], poses=res.poses[keep],
                   covariances=None if res.covariances is None else res.covariances[keep],
                   velocities_mps=None if res.velocities_mps is None else res.velocities_mps[keep])


def merge_reports(parts: list[dict[str, SourceReport]], shares: list[dict[str, float]] | None = None
                  ) -> dict[str, SourceReport]:
    """The chunks' counters summed; ``shares`` (per chunk, per source): the part of each chunk's samples in its
    kept span, by which its updates, predictions and notes are counted, so the overlaps' are not counted twice
    (``PER_CHUNK_NOTES`` whole). Rejections are summed as they are: they gather where a source misbehaves (a
    slip, a jump), which a share of the samples does not follow; one in an overlap is counted by both chunks."""
    out: dict[str, dict] = {}
    for i, reports in enumerate(parts):
        for src, r in reports.items():
            f = 1.0 if shares is None else shares[i].get(src, 1.0)
            m = out.setdefault(src, {"updates": 0.0, "predictions": 0.0, "rejected": {}, "notes": {}, "by_kind": {}})
            m["updates"] += f * r.updates
            m["predictions"] += f * r.predictions
            for k, v in r.rejected.items():
                m["rejected"][k] = m["rejected"].get(k, 0) + v
            for k, v in r.notes.items():
                m["notes"][k] = m["notes"].get(k, 0.0) + (v if k in PER_CHUNK_NOTES else f * v)
            for kind, c in r.by_kind.items():
                t = m["by_kind"].setdefault(kind, {"updates": 0.0, "outlier": 0})
                for key, v in c.items():
                    t[key] = t.get(key, 0.0) + (f * v if key == "updates" else v)
    merged: dict[str, SourceReport] = {}
    for src, m in out.items():
        r = merged[src] = SourceReport(received=sum(p[src].received for p in parts if src in p),
                                       updates=_count(m["updates"]), predictions=_count(m["predictions"]))
        for k, v in m["rejected"].items():
            r.reject(k, v)
        for k, v in m["notes"].items():
            r.note(k, _count(v))
        r.by_kind = {kind: {key: _count(v) for key, v in c.items()} for kind, c in m["by_kind"].items()}
    return merged


def _count(x: float) -> int:
    return int(np.floor(x + 0.5))


def kept_shares(chunk: dict[str, np.ndarray], kept_ns: tuple[int, int, bool]) -> dict[str, float]:
    """Per source, the share of a chunk's samples (``chunk``: source -> stamps fused) in its kept span
    (``kept_ns``: from, to, whether ``to`` is in it)."""
    a, b, closed = kept_ns
    out = {}
    for src, st in chunk.items():
        n = int(np.count_nonzero((st >= a) & ((st <= b) if closed else (st < b))))
        out[src] = n / len(st) if len(st) else 1.0
    return out


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


__all__ = ["align_onto", "carried", "cross_fade", "enu_shift", "from_enu", "kept_shares", "merge_reports",
           "merge_wheel_checks", "taken"]
