"""Gaps of the gyro inside the motion sources' coverage, and what bridges them.

Between two IMU samples further apart than the gap threshold the gyro says nothing about the turn rate. Where
the wheels kept running, their yaw rate (twist.angular.z) measures it there, even where the default selection
leaves it out beside the gyro (``wheel_yaw``): without the gyro it is the best there is. Where nothing measures
the turn rate, the planar filter lets it decay (``GAP_TAU_S``) instead of holding its last value: a held rate
turns the heading without end while the wheels keep the speed up.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .wheel_yaw import MAX_SCALE_OFF as MAX_YAW_SCALE_OFF
from .wheel_yaw import SPEED_SHARE_Z, unchecked_clause


@dataclass
class GyroGaps:
    """The gyro's gaps (``starts``/``ends``: its runs of data, as ``Prepared.coverage``) and the wheel yaw rates
    to use inside them (per wheel sample, NaN outside the gaps or where the selection already uses it)."""

    run_starts: list[int]
    run_ends: list[int]
    yaw_radps: np.ndarray | None = None
    yaw_var: np.ndarray | None = None
    share_radpm: float = 0.0  # the wheels' yaw rate's share of their speed taken out (unequal radii)
    selected: int = 0  # wheel yaw rates inside the gaps the selection itself uses
    said: str | None = None  # the note said of them (``say_gyro_gaps``)
    outputs: int = 0  # output stamps added inside the gaps (the wheel or odometry stamps there)

    @property
    def count(self) -> int:
        return len(self.run_starts) - 1

    @property
    def lengths_s(self) -> np.ndarray:
        return (np.array(self.run_starts[1:]) - np.array(self.run_ends[:-1])) * 1e-9

    @property
    def bridging_yaw(self) -> int:
        return 0 if self.yaw_radps is None else int(np.count_nonzero(np.isfinite(self.yaw_radps)))

    @property
    def turning_yaw(self) -> int:
        """Wheel yaw rates that turn the heading inside the gaps: the bridging ones and the selection's own."""
        return self.bridging_yaw + self.selected


def in_gyro_gap(imu_ns: np.ndarray, threshold_ns: int, stamps_ns: np.ndarray) -> np.ndarray:
    """Stamps strictly between two IMU samples further apart than ``threshold_ns``."""
    if len(imu_ns) < 2:
        return np.zeros(len(stamps_ns), bool)
    k = np.searchsorted(imu_ns, stamps_ns, side="right")
    inside = (k > 0) & (k < len(imu_ns))
    kk = np.clip(k, 1, len(imu_ns) - 1)
    return inside & (imu_ns[kk] - imu_ns[kk - 1] > threshold_ns) & (stamps_ns > imu_ns[kk - 1])


def gap_yaw_rates(imu_ns: np.ndarray, threshold_ns: int, wheel_ns: np.ndarray, raw_yaw: np.ndarray,
                  raw_var: np.ndarray, used_yaw: np.ndarray | None, scale: float, scale_unsure: float,
                  share_radpm: float, speed_mps: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The wheels' yaw rates inside the gyro's gaps, NaN elsewhere and where ``used_yaw`` (the selection's) already
    has a value: plus ``share_radpm`` times the speed (unequal radii, as the weighing measured them), divided by the
    yaw ``scale`` the weighing found; their variance widened by ``scale_unsure`` (the scale's |c| + sigma) times the
    rate, as the weighing widens the rates it lets in."""
    gap = in_gyro_gap(imu_ns, threshold_ns, wheel_ns) & np.isfinite(raw_yaw)
    if used_yaw is not None:
        gap &= ~np.isfinite(used_yaw)
    yaw = (raw_yaw + share_radpm * np.nan_to_num(speed_mps)) / scale
    var = np.nan_to_num(raw_var, nan=0.0) / scale**2 + (scale_unsure * yaw) ** 2
    return np.where(gap, yaw, np.nan), np.where(gap, var, np.nan)


def gap_note(gaps: GyroGaps, wheel_speed: bool, odom: bool, gps: bool, estimator: str) -> str:
    """The one line said about the gyro's gaps: how many, the longest, what bridged them."""
    n, longest = gaps.count, float(gaps.lengths_s.max())
    head = f"imu: {n} gap{'s' if n > 1 else ''} in the gyro (the longest {longest:.1f} s)"
    share = f", their speed's share {-gaps.share_radpm:+.2g} rad/m taken out: unequal radii" \
        if gaps.share_radpm else ""
    if estimator == "graph":
        turn = "the factor graph took the 3D filter's increment (the heading " + (
            "following the wheels' yaw rate)" if gaps.turning_yaw else "held)")
    elif gaps.turning_yaw:
        turn = f"the heading followed the wheels' yaw rate ({gaps.turning_yaw} messages{share})"
    elif odom:
        turn = "the heading followed the odometry poses"
    elif estimator == "planar":
        turn = "the turn rate decayed to zero (nothing else measures it)"
    else:
        turn = "the heading was held"
    wheels = wheel_speed and not (gps and estimator == "graph")  # the graph's position: GPS factors first
    where = "the wheels' speed" if wheels else "the GPS fixes" if gps else ""
    return f"{head}: {turn}" + (f" and the position {where}" if where else "") + " there"


def find_gyro_gaps(prep, runs: list[tuple[int, int]], raw_wheel) -> None:
    """``prep.gyro_gaps`` (a ``timeline.Prepared``): the gyro's gaps between its ``runs`` of data and the wheel yaw
    rates that may bridge them (``raw_wheel``: before the weighing left any out); ``say_gyro_gaps`` once the
    estimator is known."""
    if len(runs) < 2:
        return
    gaps = GyroGaps([a for a, _ in runs], [b for _, b in runs])
    w = prep.wheel
    if w is not None:
        check = prep.wheel_yaw_check or {}
        c, c_sigma = check.get("scale_off"), check.get("scale_off_sigma") or 0.0
        used = w.yaw_rate_radps if "yaw_rate" in prep.use["wheel"] else None
        if used is not None:
            gaps.selected = int(np.count_nonzero(in_gyro_gap(prep.imu.stamps_ns, prep.imu_gap_ns, w.stamps_ns)
                                                 & np.isfinite(used)))
        if c is None or abs(c) <= MAX_YAW_SCALE_OFF:  # a zero, flipped or deg/s yaw rate never bridges
            share, share_sigma = check.get("speed_share_radpm"), check.get("speed_share_sigma")
            if share is not None and abs(share) > SPEED_SHARE_Z * share_sigma:  # unequal radii: taken out
                gaps.share_radpm = share
            gaps.yaw_radps, gaps.yaw_var = gap_yaw_rates(
                prep.imu.stamps_ns, prep.imu_gap_ns, w.stamps_ns, raw_wheel.yaw_rate_radps, raw_wheel.yaw_rate_var,
                used, 1.0 - (c or 0.0), abs(c or 0.0) + c_sigma, gaps.share_radpm, raw_wheel.velocity_mps[:, 0])
    prep.gyro_gaps = gaps


def say_gyro_gaps(prep, estimator: str, graph: bool = False) -> None:
    """The gyro's gaps in one note and the wheel yaw rates bridging them counted (the planar filter and the 3D EKF
    follow them; the factor graph bridges the gap with the 3D filter's increment; the complementary filter holds the
    heading)."""
    gaps = prep.gyro_gaps
    if gaps is None:
        return
    if estimator not in ("planar", "ekf"):
        gaps.yaw_radps = gaps.yaw_var = None
    elif gaps.bridging_yaw and not graph:
        rep = prep.reports["wheel"]
        rep.note("gyro_gap_yaw", gaps.bridging_yaw)
        check = prep.wheel_yaw_check or {}
        if check.get("used"):  # the weighing left them out as unchecked: used after all
            left = rep.rejected.get("yaw_unchecked", 0) - gaps.bridging_yaw
            rep.rejected.pop("yaw_unchecked", None)
            rep.reject("yaw_unchecked", max(left, 0))
            n = check["unchecked_samples"]
            check["why"] = check["why"].replace(unchecked_clause(n), unchecked_clause(n, min(gaps.bridging_yaw, n)))
    estimator = "graph" if graph else estimator
    speed = prep.wheel is not None and bool({"speed", "velocity"} & prep.use["wheel"])
    gaps.said = gap_note(gaps, speed, prep.odom is not None, prep.gps is not None, estimator)
    prep.notes.append(gaps.said)
