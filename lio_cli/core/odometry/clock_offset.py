"""Online estimate of a small IMU-LiDAR clock offset (tens of milliseconds) while odometry runs.

Registration poses carry the LiDAR's timing; the gyro its own. Over a window of healthy IMU-primed scans the
rotation increments of the registered poses are aligned in time with the gyro (``calibration.time_offset``),
and an offset that is clearly there and sharply determined is applied to every later IMU sample. Windows
without enough rotation to time anything are simply skipped. After the last scan one closing estimate over
the poses left measures what the rounds left (``estimate_s``): too late for the online run, in time for an
offline pass over the same log. (The rotation the alignment finds alongside is
not used to judge the extrinsic: a vehicle turning about one axis leaves it undetermined about that axis.)
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from ...errors import InputError
from ..calibration.time_offset import estimate_time_offset

WINDOW_S = 2.5  # registration poses per estimate (each round measures part of what is left: short rounds converge sooner)
MAX_OFFSET_S = 0.1  # larger offsets are a clock mismatch, refused before the run
APPLY_SIGMA_S = 0.002  # apply only a sharply determined offset...
APPLY_SIGMA_DOUBTED_S = 0.005  # ...or this sharp, in a window the IMU state doubted scans of (the doubt is evidence)
APPLY_MIN_S = 0.001  # ...that is clearly there...
APPLY_SIGMAS = 3.5  # ...at least this many sigma from zero (fewer applies offsets that are not there)
ROUNDS = 12  # estimates at most (each later one measures what the earlier left)
FINAL_WINDOW_S = 2.3  # the closing estimate over the poses the last round left (its overlap with the IMU: >= 2 s)


@dataclass
class ClockOffsetTracker:
    """Collects registration poses (T_world_lidar) and gyro samples; proposes offset corrections."""

    applied_s: float = 0.0  # total correction applied so far
    residual_s: float = 0.0  # measured (>= APPLY_SIGMAS sigma) but not applied: too small to apply online, or after the last scan
    estimates: list[dict] = field(default_factory=list)
    _stamps: list[int] = field(default_factory=list)
    _poses: list[np.ndarray] = field(default_factory=list)
    _imu_stamps: list[np.ndarray] = field(default_factory=list)
    _gyro: list[np.ndarray] = field(default_factory=list)
    _rounds: int = 0
    doubted: bool = False  # the window holds a doubted scan's pose (see APPLY_SIGMA_DOUBTED_S)

    @property
    def done(self) -> bool:
        return self._rounds >= ROUNDS

    def add_imu(self, stamps_ns: np.ndarray, gyro_radps: np.ndarray) -> None:
        if not self.done:
            self._imu_stamps.append(np.asarray(stamps_ns, dtype=np.int64))
            self._gyro.append(np.asarray(gyro_radps, dtype=np.float64))

    def add_pose(self, stamp_ns: int, T_world_lidar: np.ndarray, doubted: bool = False) -> None:
        """``doubted``: the pose of a scan the IMU state could not explain (LiDAR-only), which marks the window."""
        if not self.done:
            self.doubted = self.doubted or doubted
            self._stamps.append(int(stamp_ns))
            self._poses.append(T_world_lidar)

    def reset(self) -> None:
        """Forget the window (a lost track or a time gap breaks it)."""
        self._stamps, self._poses, self._imu_stamps, self._gyro = [], [], [], []
        self.doubted = False

    @property
    def estimate_s(self) -> float:
        """The offset as measured by the end: what was applied plus a residual measured but not applied."""
        return self.applied_s + self.residual_s

    def close(self, gyro_bias_radps: np.ndarray, at_scan: int) -> None:
        """After the last scan: one more estimate over the window left (at least ``FINAL_WINDOW_S``). Nothing is
        applied any more; a sharply determined residual joins ``estimate_s`` (an offline pass over the log,
        as ``lio deskew``'s, uses it)."""
        if not self.done:
            self._measure(gyro_bias_radps, at_scan, FINAL_WINDOW_S, final=True)
            self._rounds = ROUNDS

    def propose(self, gyro_bias_radps: np.ndarray, at_scan: int) -> int:
        """Nanoseconds to add to every later IMU stamp (0: nothing to apply, or the window is not full yet)."""
        offset = self._measure(gyro_bias_radps, at_scan, WINDOW_S, final=False)
        return 0 if offset is None else int(round(offset * 1e9))

    def _measure(self, gyro_bias_radps: np.ndarray, at_scan: int, window_s: float, final: bool) -> float | None:
        """The offset to apply from the window collected (None: nothing to apply, or the window is short)."""
        if self.done or len(self._stamps) < 3 or (self._stamps[-1] - self._stamps[0]) * 1e-9 < window_s:
            return None
        stamps, poses = np.asarray(self._stamps, dtype=np.int64), np.stack(self._poses)
        imu_stamps, gyro = np.concatenate(self._imu_stamps), np.concatenate(self._gyro)
        doubted = self.doubted
        self.reset()
        self._rounds += 1
        order = np.argsort(imu_stamps, kind="stable")
        imu_stamps, gyro = imu_stamps[order], gyro[order]
        keep = np.concatenate([[True], np.diff(imu_stamps) > 0])
        try:
            with np.errstate(all="ignore"):
                est = estimate_time_offset(stamps, poses, imu_stamps[keep], gyro[keep], gyro_bias_radps=gyro_bias_radps,
                                           max_offset_s=MAX_OFFSET_S)
        except InputError as err:  # not enough rotation in this window to time anything: try the next one
            self.estimates.append({"scan": at_scan, "applied": False, "reason": str(err).split(";")[0]})
            return None
        offset, sigma = est.imu_time_offset_s, est.sigma_s
        limit = APPLY_SIGMA_DOUBTED_S if doubted else APPLY_SIGMA_S
        sharp = sigma <= limit and abs(offset) >= APPLY_SIGMAS * sigma  # clearly there, sharply determined
        apply = sharp and abs(offset) >= APPLY_MIN_S and not final
        entry = {"scan": at_scan, "offset_s": round(offset, 6), "sigma_s": round(sigma, 6), "applied": bool(apply)}
        self.estimates.append({**entry, "final": True} if final else entry)
        if not apply:
            if sigma <= APPLY_SIGMA_S:
                self.residual_s = offset if sharp else 0.0
                if not final and abs(offset) < APPLY_MIN_S and sigma <= APPLY_MIN_S:
                    # the clocks agree to under a millisecond, sharply (not merely under APPLY_SIGMAS): nothing to apply
                    self._rounds = ROUNDS
            return None
        self.residual_s = 0.0
        self.applied_s += offset
        return offset
