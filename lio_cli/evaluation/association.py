"""Timestamp association of two trajectories (same semantics as evo's ``associate_trajectories``).

The trajectory with fewer poses drives: each of its stamps is paired with the nearest stamp of the other
within ``max_diff_ns`` (ties go to the earlier stamp); or, with ``method="interpolate"``, the denser
trajectory is resampled at the matched stamps (linear position, slerp rotation). ``offset_ns`` is added to
the estimate's stamps for matching only. Time is int64 ns throughout, so nothing is lost to float seconds.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..errors import InputError
from ..io.files.trajectory import format_stamp
from ..geometry import interpolate_poses
from ..model.trajectory import Trajectory

METHODS = ("nearest", "interpolate")
_NO_MATCH = np.iinfo(np.int64).max


@dataclass
class Association:
    """Paired poses: ``ref.poses[k]`` and ``est.poses[k]`` belong together; stamps are the reference's."""

    ref: Trajectory
    est: Trajectory
    ref_indices: np.ndarray  # into the input reference (-1 where it was interpolated)
    est_indices: np.ndarray  # into the input estimate (-1 where it was interpolated)
    method: str
    interpolated: str | None  # "reference", "estimate" or None


def match_nearest(short_ns: np.ndarray, long_ns: np.ndarray, max_diff_ns: int) -> tuple[np.ndarray, np.ndarray]:
    """Indices (into short, into long) of each short stamp's nearest long stamp within ``max_diff_ns``."""
    short_ns = np.asarray(short_ns, dtype=np.int64)
    long_ns = np.asarray(long_ns, dtype=np.int64)
    upper = np.minimum(np.searchsorted(long_ns, short_ns, side="right"), len(long_ns) - 1)
    diff_up = long_ns[upper] - short_ns  # negative only past the last long stamp
    diff_low = np.where(upper > 0, short_ns - long_ns[np.maximum(upper - 1, 0)], _NO_MATCH)
    inside = (short_ns >= long_ns[0] - max_diff_ns) & (short_ns <= long_ns[-1] + max_diff_ns)
    take_up = inside & (diff_up <= max_diff_ns) & (diff_up < diff_low)
    take_low = inside & ~take_up & (diff_low <= max_diff_ns) & (diff_low <= diff_up)
    ok = take_up | take_low
    idx_long = np.where(take_up, upper, upper - 1)
    return np.flatnonzero(ok), idx_long[ok]


def associate(
    ref: Trajectory,
    est: Trajectory,
    max_diff_ns: int = 10_000_000,
    offset_ns: int = 0,
    method: str = "nearest",
) -> Association:
    """Pair the poses of ``ref`` and ``est``; raise InputError saying why when nothing pairs."""
    if method not in METHODS:
        raise InputError(f"unknown association method '{method}' (choose from {', '.join(METHODS)})")
    est_longer = len(est) > len(ref)
    if est_longer:  # short = ref, long = est shifted by +offset
        i_short, i_long = match_nearest(ref.stamps_ns, est.stamps_ns + offset_ns, max_diff_ns)
        i_ref, i_est = i_short, i_long
    else:  # short = est, long = ref shifted by -offset
        i_short, i_long = match_nearest(est.stamps_ns, ref.stamps_ns - offset_ns, max_diff_ns)
        i_ref, i_est = i_long, i_short
    if len(i_short) == 0:
        raise InputError(explain_no_match(ref, est, max_diff_ns, offset_ns))
    interpolated = None
    if method == "interpolate":
        if est_longer:
            if len(est) < 2:  # pragma: no cover - est_longer implies >= 2 poses
                raise InputError(f"{est.name}: cannot interpolate fewer than two poses")
            q = ref.stamps_ns[i_ref] - offset_ns
            est_s = Trajectory(q, interpolate_poses(est.stamps_ns, est.poses, q), est.name)
            ref_s = Trajectory(ref.stamps_ns[i_ref], ref.poses[i_ref], ref.name)
            i_est = np.full(len(i_ref), -1)
            interpolated = "estimate"
        else:
            if len(ref) < 2:
                raise InputError(f"{ref.name}: cannot interpolate a reference of fewer than two poses")
            q = est.stamps_ns[i_est] + offset_ns
            ref_s = Trajectory(q, interpolate_poses(ref.stamps_ns, ref.poses, q), ref.name)
            est_s = Trajectory(est.stamps_ns[i_est], est.poses[i_est], est.name)
            i_ref = np.full(len(i_est), -1)
            interpolated = "reference"
    else:
        ref_s = Trajectory(ref.stamps_ns[i_ref], ref.poses[i_ref], ref.name)
        est_s = Trajectory(est.stamps_ns[i_est], est.poses[i_est], est.name)
    return Association(ref_s, est_s, i_ref, i_est, method, interpolated)


def _span(t: Trajectory) -> str:
    return f"{t.stamps_ns[0] / 1e9:.6f}..{t.stamps_ns[-1] / 1e9:.6f} s"


def explain_no_match(ref: Trajectory, est: Trajectory, max_diff_ns: int, offset_ns: int) -> str:
    """One line: why no stamp pairs, with both time ranges and the flag that likely fixes it."""
    head = (
        f"no matching timestamps between {ref.name} ({_span(ref)}) and {est.name} ({_span(est)}) "
        f"within --t-max-diff {max_diff_ns / 1e9:g} s (offset {offset_ns / 1e9:g} s)"
    )
    r0, e0 = abs(float(ref.stamps_ns[-1])), abs(float(est.stamps_ns[-1]))
    # a unit mix-up scales the stamps and the span alike: epoch stamps against stamps from 0 (KITTI times.txt, a
    # relative clock) differ as much in their ends, but not in their spans
    r_span, e_span = float(ref.stamps_ns[-1] - ref.stamps_ns[0]), float(est.stamps_ns[-1] - est.stamps_ns[0])
    span_ratio = e_span / r_span if r_span > 0 and e_span > 0 else None
    if r0 > 0 and e0 > 0:
        ratio = e0 / r0
        for factor, unit in ((1e9, "ns"), (1e6, "us"), (1e3, "ms")):
            for f, name, flag in ((factor, est.name, "--est-stamp-unit"), (1 / factor, ref.name, "--gt-stamp-unit")):
                if 0.2 * f < ratio < 5 * f and (span_ratio is None or 0.2 * f < span_ratio < 5 * f):
                    return f"{head}: {name}'s stamps look like {unit} read as seconds; pass {flag} {unit}"
    shifted = est.stamps_ns + offset_ns
    if shifted[0] > ref.stamps_ns[-1] or shifted[-1] < ref.stamps_ns[0]:
        gap_ns = int(ref.stamps_ns[0] - est.stamps_ns[0])  # from the integer: an epoch-sized gap keeps its ns
        gap = format_stamp(gap_ns).rstrip("0").rstrip(".")
        return f"{head}: the time ranges do not overlap; if the clocks differ by a constant, pass --t-offset {gap}"
    i = np.clip(np.searchsorted(ref.stamps_ns, shifted), 1, len(ref) - 1) if len(ref) > 1 else np.zeros(len(est), int)
    gaps = np.minimum(np.abs(ref.stamps_ns[i] - shifted), np.abs(ref.stamps_ns[np.maximum(i - 1, 0)] - shifted))
    closest = float(gaps.min()) / 1e9
    return f"{head}: the closest stamps are {closest:.6g} s apart; raise --t-max-diff above that (--interpolate pairs within it too)"
