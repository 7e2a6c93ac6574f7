"""Whether the GPS fixes agree with the motion sources, decided once per run: the GPS-fused trajectory, or the one
fused without GPS placed on the fixes where the fixes' slow error explains what it leaves (``shape``).

``asked``: whether the test is run at all, from the whole run's GPS-fused result (a claim the innovations showed
optimistic) and the whole run's wheel check (wheels the IMU verified, or the wheels' speed it backs). ``judged``:
the verdict on the two trajectories. ``fuse`` asks both on one run; a log fused in pieces (``GpsJudge``, from
``api.judge_gps``) asks them once on its stitched pieces, never piece by piece: a piece of a minute shows none of
the heading drift a whole log's fixes reveal.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from . import shape
from .inputs import GpsSeries
from .pieces import turned_handover
from .result import FuseResult, anchor_to_origin, enu_origin

WHOLE_LOG_NOTES = ("jumps", "jump_kept", "dropouts")  # GPS notes of the whole log's fixes, not of a piece's fusion


def optimistic(gps: GpsSeries, fused: FuseResult) -> bool:
    """The GPS-fused run raised the fixes' claimed noise for ``shape.OPTIMISTIC_SHARE`` of them or more."""
    raised = fused.reports["gps"].notes.get("noise_raised", 0) if "gps" in fused.reports else 0
    return raised >= shape.OPTIMISTIC_SHARE * len(gps)


def wheel_speed_backed(wheel_check: dict | None) -> bool:
    """The wheels' speed as the IMU checked it (``wheel_slip``): its scale measured and every slip bridged, or no
    slip and the accelerometer's scale consistent with 1 at 99 % (one-dof chi-square; a steady speed measures it
    only roughly, and without a slip an unverified check applied no scale)."""
    speed = wheel_check or {}
    if speed.get("verified"):
        return True
    scale, sigma = speed.get("scale"), speed.get("scale_sigma")
    if speed.get("slips", 1) or scale is None or not sigma:
        return False
    return ((scale - 1.0) / sigma) ** 2 <= shape.CHI2_1_99


def judged(gps: GpsSeries, notes: list[str], fused: FuseResult, free: FuseResult, asked: bool) -> FuseResult:
    """The run without GPS (``free``), placed on the fixes, where the fixes' real error explains what it leaves
    (``shape``); else the GPS-fused ``fused``. ``asked``: a claim found optimistic or wheels the IMU verified; else
    only fixes scattering beyond their claim count (the wheels' speed backed). The verdict goes to ``notes``.

    An honest claim is fused as it is; but a filter that follows a receiver's slow error shows no optimism in its
    innovations, so wheels the IMU verified (speed and yaw rate) have the shape tested too, and so has a track
    whose speed the accelerometer backs where the fixes scatter about it beyond their claim."""
    same = len(free) == len(fused) and np.array_equal(free.stamps_ns, fused.stamps_ns)
    test = shape.consistent(gps, free.stamps_ns, free.poses) if same and len(free) else None
    if test is not None and "handover" in free.info:  # the next piece's start: the motion sources' own, placed
        fused.info["handover"] = turned_handover(free.info["handover"], test.T[:3, :3])
    if test is None or not (asked or test.claim_exceeded):
        return fused
    fused.info["gps_shape"] = {**test.to_dict(), "kept": "gps fused"}
    if not test.consistent:
        notes.append("gps: the fixes disagree with the motion sources beyond their slow error: GPS shapes the track")
        return fused
    R = test.T[:3, :3]
    on_fixes = test.T @ free.poses
    poses = anchor_to_origin(on_fixes)
    vel = None if free.velocities_mps is None else free.velocities_mps @ R.T
    cov = free.covariances
    if cov is not None:
        cov = cov.copy()
        cov[:, :3, :3] = R @ cov[:, :3, :3] @ R.T
        cov[:, :3, 3:] = R @ cov[:, :3, 3:]
        cov[:, 3:, :3] = cov[:, 3:, :3] @ R.T
    notes.append("gps: the motion sources' track kept and placed on the fixes (their slow error explains the rest)")
    info = {**fused.info, "gps_shape": {**test.to_dict(), "kept": "motion sources, placed on GPS"},
            "smoother": {**(free.info.get("smoother") or {}), "why": "the run without GPS, placed on the fixes (their "
                         "slow error explains it): " + str((free.info.get("smoother") or {}).get("why"))},
            "start": free.info.get("start"), "world_yaw_from": "gps"}
    return FuseResult(free.stamps_ns, poses, cov, vel, free.estimator, free.smoothed, fused.reports, info,
                      enu_origin(on_fixes, np.zeros(2)))


@dataclass
class GpsJudge:
    """The GPS agreement of a log fused in pieces, judged on the whole log: its fixes as the whole log's timeline
    assessed them (``accepted``, sigmas), its wheel check (``wheels``: (verified, speed backed), computed only
    when asked: the check runs over the whole log), whether the agreement is tested at all (``tests``) and the
    counts of the whole log's own GPS notes, which its pieces cannot add up (a jump across a seam)."""

    gps: GpsSeries
    wheels: Callable[[], tuple[bool, bool]]
    tests: bool
    counts: dict[str, int]  # the whole log's GPS notes of its own (``WHOLE_LOG_NOTES``)

    @property
    def jumps_ns(self) -> np.ndarray:
        """The stamps of the fixes the whole log's jump test left out (``FuseOptions.gps_jumps_ns``)."""
        return self.gps.stamps_ns[~np.asarray(self.gps.accepted, bool)]

    def asks(self, fused: FuseResult) -> tuple[bool, bool]:
        """(whether the GPS-free pieces are needed, whether the test counts whatever it finds) for the stitched
        GPS-fused pieces ``fused``."""
        if optimistic(self.gps, fused):
            return True, True
        verified, backed = self.wheels()
        return verified or backed, verified

    def judge(self, fused: FuseResult, free: FuseResult, asked: bool) -> FuseResult:
        """``judged`` on the stitched pieces; its note joins ``fused``'s notes."""
        notes = fused.info.setdefault("notes", [])
        return judged(self.gps, notes, fused, free, asked)


__all__ = ["WHOLE_LOG_NOTES", "GpsJudge", "judged", "optimistic", "wheel_speed_backed"]
