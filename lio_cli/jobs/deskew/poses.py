"""The odometry's poses as the writing pass of ``lio deskew`` takes them: scan by scan, as they settle.

The odometry hands on each scan's pose once it can no longer change (``SettledPose``: after the start-up
window is replaced by its IMU-primed replay), with the gyro bias and IMU clock shift it had then. The
writing pass reads them through a ``PoseFeed``, from a list once the odometry is done or, while the odometry
still runs in the other process, from a pipe (``deskew_helper``): both give the same bytes.

For a sweep the feed builds the cubic ``PoseSpline`` over the few poses around it; it equals the spline over
the whole trajectory there (the same four poses around each query, the same ends). How far the ends are
extrapolated is the median interval of the first ``_STEP_POSES`` poses at the start, of all at the end. The
rotation within a sweep is integrated with the gyro bias of the pose at the sweep's reference instant (the
state the odometry had once that pose was final: after that scan's update, or after the start-up window's
replay) and with the IMU clock offset the odometry had applied by then, unless the offset it measured by its
end differs from any of those by more than ``OFFSET_AGREE_NS``: then that final offset for every scan
(``final_offset_ns``; its online rounds converge over tens of seconds, and the closing one sees the whole
log).
"""

from __future__ import annotations

from collections import deque
from collections.abc import Iterator

import numpy as np

from ...core.odometry.clock_offset import APPLY_MIN_S
from ...core.deskew.sweep_motion import PoseSpline
from ..odom.job import SettledPose

_STEP_POSES = 21  # the extrapolation step is the median interval of this many first poses
_KEEP = 600  # poses kept behind the latest sweep (a scan that much out of order is not covered)
_BEHIND = f"more than {_KEEP} scans out of order"
OFFSET_AGREE_NS = round(APPLY_MIN_S * 1e9)  # the clock tracker's own threshold for applying an offset


class PoseFeed:
    """Settled poses from ``batches`` (lists of ``SettledPose`` in order); ``spline`` and ``imu_state`` for
    one sweep at a time."""

    def __init__(self, batches: Iterator[list[SettledPose]], *, max_gap_ns: int | None, offset_ns: int,
                 default_bias: np.ndarray, final_offset_ns: int | None = None) -> None:
        self._batches = batches
        self.max_gap_ns, self.offset_ns, self.default_bias = max_gap_ns, offset_ns, default_bias
        self.final_offset_ns = final_offset_ns  # every scan's IMU clock offset, when given
        self._poses: deque[SettledPose] = deque()
        self._stamps: deque[int] = deque()
        self.dropped = 0  # poses let go from the front
        self.ended = False
        self.first_ns: int | None = None
        self.step_ns: int | None = None  # the start's extrapolation
        self._steps: list[int] = []  # every interval: the first ones for the start's extrapolation, all for the end's
        self._end_step_ns: int | None = None
        self._prev_i0: int | None = None  # the previous sweep's first pose (counted from the first pose ever)

    def _pull(self) -> bool:
        batch = next(self._batches, None)
        if batch is None:
            self.ended = True
            if self.step_ns is None:  # fewer than _STEP_POSES poses in all
                self.step_ns = int(np.median(self._steps)) if self._steps else 0
            return False
        for p in batch:
            if self._stamps and p.stamp_ns <= self._stamps[-1]:
                raise ValueError(f"settled poses out of order: {p.stamp_ns} after {self._stamps[-1]}")
            if self.first_ns is None:
                self.first_ns = p.stamp_ns
            else:
                self._steps.append(p.stamp_ns - self._stamps[-1])
                if self.step_ns is None and len(self._steps) == _STEP_POSES - 1:
                    self.step_ns = int(np.median(self._steps))
            self._poses.append(p)
            self._stamps.append(p.stamp_ns)
        return True

    def _ready(self, t1_ns: int) -> None:
        """Pull until two poses lie beyond ``t1_ns`` (the cubic's nodes) and the step is known, or the end."""
        while not self.ended and (self.step_ns is None or len(self._stamps) < 2 or self._stamps[-2] <= t1_ns):
            self._pull()

    def drain(self) -> None:
        """Take the poses still to come (the end of the odometry)."""
        while not self.ended:
            self._pull()

    @property
    def last_ns(self) -> int | None:
        return self._stamps[-1] if self._stamps else None

    def spline(self, t0_ns: int, t1_ns: int) -> PoseSpline | str:
        """The spline over the poses around [t0, t1] (the whole trajectory's there), or why there is none."""
        self._ready(t1_ns)
        if not self._stamps:
            return "before the trajectory starts"
        st = np.fromiter(self._stamps, dtype=np.int64, count=len(self._stamps))
        n = len(st)
        i0 = int(np.searchsorted(st, t0_ns, side="right")) - 1
        if i0 < 1 and self.dropped:  # the pose before it (a node of its cubic) is gone
            return _BEHIND
        i1 = int(np.searchsorted(st, t1_ns, side="right")) - 1
        a, b = max(0, i0 - 1), min(n - 1, max(i1, 0) + 2)
        while b - a + 1 < 4 and (a > 0 or b < n - 1):  # the cubic's four nodes at either end
            a, b = (a - 1, b) if a > 0 else (a, b + 1)
        # let go of poses far behind this sweep and the one before (one sweep stamped far ahead, a broken
        # scan, does not take the poses its neighbours need)
        now = i0 + self.dropped
        drop = min(now, now if self._prev_i0 is None else self._prev_i0) - _KEEP - self.dropped
        self._prev_i0 = now
        if drop > 0:
            for _ in range(drop):
                self._poses.popleft()
                self._stamps.popleft()
            self.dropped += drop
            a, b = a - drop, b - drop
        # ends of the whole trajectory extrapolate; a window inside it never reaches its own ends
        at_end = self.ended and b == len(self._stamps) - 1
        if at_end and self._end_step_ns is None:
            self._end_step_ns = int(np.median(self._steps)) if self._steps else 0
        step = self._end_step_ns if at_end else self.step_ns if a == 0 and not self.dropped else 0
        window = [self._poses[i] for i in range(a, b + 1)]
        return PoseSpline(np.array([p.stamp_ns for p in window], dtype=np.int64), np.stack([p.pose for p in window]),
                          cubic=True, extrapolate_ns=step, max_gap_ns=self.max_gap_ns)

    def imu_state(self, t_ref_ns: int) -> tuple[np.ndarray, int]:
        """(gyro bias, IMU clock offset in ns) of the odometry once the pose at ``t_ref_ns`` was final (the first
        pose from there on, else the last)."""
        st = self._stamps
        j = min(int(np.searchsorted(np.fromiter(st, dtype=np.int64, count=len(st)), t_ref_ns)), len(st) - 1)
        p = self._poses[j]
        bias = self.default_bias if p.gyro_bias_radps is None else p.gyro_bias_radps
        return bias, self.offset_ns + p.imu_shift_ns if self.final_offset_ns is None else self.final_offset_ns


__all__ = ["OFFSET_AGREE_NS", "PoseFeed"]
