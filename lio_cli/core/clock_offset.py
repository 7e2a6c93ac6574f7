"""Online estimate of a small IMU-LiDAR clock offset (tens of milliseconds) while odometry runs.

Registration poses carry the LiDAR's timing; the gyro its own. Over a window of healthy IMU-primed scans the
rotation increments of the registered poses are aligned in time with the gyro (``calibration.time_offset``),
and an offset that is clearly there and sharply determined is applied to every later IMU sample. Windows
without enough rotation to time anything are simply skipped. (The rotation the alignment finds alongside is
not used to judge the extrinsic: a vehicle turning about one axis leaves it undetermined about that axis.)
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from ..errors import InputError
from .calibration.time_offset import estimate_time_offset

WINDOW_S = 5.0  # registration poses per estimate
MAX_OFFSET_S = 0.1  # larger offsets are a clock mismatch, refused before the run
APPLY_SIGMA_S = 0.002  # apply only a sharply determined offset...
APPLY_MIN_S = 0.001  # ...that is clearly there (and at least 3 sigma)
ROUNDS = 6  # estimates at most (each later one measures what the earlier left)


@dataclass
class ClockOffsetTracker:
    """Collects registration poses (T_world_lidar) and gyro samples; proposes offset corrections."""

    applied_s: float = 0.0  # total correction applied so far
    estimates: list[dict] = field(default_factory=list)
    _stamps: list[int] = field(default_factory=list)
    _poses: list[np.ndarray] = field(default_factory=list)
    _imu_stamps: list[np.ndarray] = field(default_factory=list)
    _gyro: list[np.ndarray] = field(default_factory=list)
    _rounds: int = 0

    @property
    def done(self) -> bool:
        return self._rounds >= ROUNDS

    def add_imu(self, stamps_ns: np.ndarray, gyro_radps: np.ndarray) -> None:
        if not self.done:
            self._imu_stamps.append(np.asarray(stamps_ns, dtype=np.int64))
            self._gyro.append(np.asarray(gyro_radps, dtype=np.float64))

    def add_pose(self, stamp_ns: int, T_world_lidar: np.ndarray) -> None:
        if not self.done:
            self._stamps.append(int(stamp_ns))
            self._poses.append(T_world_lidar)

    def reset(self) -> None:
        """Forget the window (a lost track or a time gap breaks it)."""
        self._stamps, self._poses, self._imu_stamps, self._gyro = [], [], [], []

    def propose(self, gyro_bias_radps: np.ndarray, at_scan: int) -> int:
        """Nanoseconds to add to every later IMU stamp (0: nothing to apply, or the window is not full yet)."""
        if self.done or len(self._stamps) < 3 or (self._stamps[-1] - self._stamps[0]) * 1e-9 < WINDOW_S:
            return 0
        stamps, poses = np.asarray(self._stamps, dtype=np.int64), np.stack(self._poses)
        imu_stamps, gyro = np.concatenate(self._imu_stamps), np.concatenate(self._gyro)
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
            return 0
        offset, sigma = est.imu_time_offset_s, est.sigma_s
        apply = sigma <= APPLY_SIGMA_S and abs(offset) >= max(APPLY_MIN_S, 3.0 * sigma)
        self.estimates.append({"scan": at_scan, "offset_s": round(offset, 6), "sigma_s": round(sigma, 6),
                               "applied": bool(apply)})
        if not apply:
            if abs(offset) < max(APPLY_MIN_S, 3.0 * sigma) and sigma <= APPLY_SIGMA_S:
                self._rounds = ROUNDS  # the clocks agree: nothing left to measure
            return 0
        self.applied_s += offset
        return int(round(offset * 1e9))
