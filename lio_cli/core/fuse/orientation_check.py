"""Does the IMU's own orientation follow its gyro? Many drivers without an attitude filter publish a constant identity
quaternion with a zero (or small) covariance; taken as attitude it pins the heading and the tilt.

Over two-second windows (one second apart) of the cleaned IMU series, the relative rotation between the window's
first and last orientation (``R_world_imu(t0)^T R_world_imu(t1)``, in the IMU frame, whatever the world frame) is
compared with the gyro integrated over the same samples. A real AHRS follows the gyro to a degree or so over a
second; a window disagrees when the two differ by more than ``AGREE_RAD`` plus ``AGREE_SHARE`` of the turn. Only
windows where the gyro turns ``MIN_TURN_RAD`` or more can tell a frozen orientation from a still platform; the
orientation fails when over ``DISAGREE_SHARE`` of at least ``MIN_WINDOWS`` such windows disagree. Cost:
O(N log N).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ...so3 import quat_xyzw_to_rot, so3_exp, so3_log_batch
from .inputs import ImuSeries, NoiseOptions
from .report import SourceReport
from .sanitize import clean_imu

STEP_NS = 1_000_000_000  # windows start this far apart
STEPS = 2  # ... and span this many steps: long enough for a ground robot's slow turns to reach MIN_TURN_RAD
MIN_TURN_RAD = np.radians(12.0)  # a window turning less cannot tell a frozen orientation from a still platform
AGREE_RAD = np.radians(4.0)  # an AHRS's error over the window plus a 1 deg/s gyro bias, with margin
AGREE_SHARE = 0.25  # plus this share of the turn: gyro scale errors and a filter lagging a fast turn
MIN_WINDOWS = 3  # turning windows needed for a verdict
DISAGREE_SHARE = 0.5  # the orientation fails when more than this share of the turning windows disagree
GAP_PERIODS = 5.0  # a window holding a pause this many median periods long is skipped


@dataclass(frozen=True)
class OrientationCheck:
    """The comparison's figures: windows turning at least ``MIN_TURN_RAD``, those disagreeing, the median error
    over the turning windows and the median turn; ``samples`` the valid orientations checked."""

    samples: int
    windows: int
    disagree: int
    median_error_rad: float
    median_turn_rad: float

    @property
    def follows(self) -> bool | None:
        """False where the orientation does not follow the gyro; None where too few windows turned to tell."""
        if self.windows < MIN_WINDOWS:
            return None
        return self.disagree <= DISAGREE_SHARE * self.windows

    def to_dict(self) -> dict:
        return {"samples": self.samples, "turning_windows": self.windows, "disagreeing": self.disagree,
                "median_error_deg": round(float(np.degrees(self.median_error_rad)), 2),
                "median_turn_deg": round(float(np.degrees(self.median_turn_rad)), 2), "follows_gyro": self.follows}


def _compose_rows(R: np.ndarray) -> np.ndarray:
    """The product along axis 1 of (W, m, 3, 3) rotations, in order, by pairwise halving."""
    while R.shape[1] > 1:
        if R.shape[1] % 2:
            R = np.concatenate([R, np.broadcast_to(np.eye(3), (R.shape[0], 1, 3, 3))], axis=1)
        R = R[:, 0::2] @ R[:, 1::2]
    return R[:, 0]


def _angle(R: np.ndarray) -> np.ndarray:
    return np.linalg.norm(so3_log_batch(R), axis=-1)


def check_orientation(imu: ImuSeries) -> OrientationCheck | None:
    """The orientation of ``imu`` (raw: cleaned here) against its gyro (module docstring); None without one."""
    imu = clean_imu(imu, NoiseOptions(), SourceReport())
    if imu.orientation_xyzw is None or imu.orientation_valid is None or len(imu) < 3:
        return None
    t, w = imu.stamps_ns, imu.gyro_radps
    dt = np.diff(t) * 1e-9
    m = max(int(round(STEP_NS * 1e-9 / float(np.median(dt)))), 1)
    n = (len(t) - 1) // m  # whole steps of m samples
    valid = int(np.count_nonzero(imu.orientation_valid))
    if n < STEPS:
        return OrientationCheck(valid, 0, 0, float("nan"), float("nan"))
    step_rel = _compose_rows(so3_exp(0.5 * (w[:-1] + w[1:]) * dt[:, None])[:n * m].reshape(n, m, 3, 3))
    step_gap = np.any((dt[:n * m] > GAP_PERIODS * np.median(dt)).reshape(n, m), axis=1)
    gyro_rel, gap = step_rel[:n - STEPS + 1], step_gap[:n - STEPS + 1].copy()
    for k in range(1, STEPS):  # a window: STEPS consecutive steps
        gyro_rel = gyro_rel @ step_rel[k:n - STEPS + 1 + k]
        gap |= step_gap[k:n - STEPS + 1 + k]
    first = np.arange(n - STEPS + 1) * m
    last = first + STEPS * m
    q = imu.orientation_xyzw
    ok = imu.orientation_valid[first] & imu.orientation_valid[last]
    ori_rel = np.broadcast_to(np.eye(3), gyro_rel.shape).copy()  # an invalid end: never judged
    ori_rel[ok] = np.swapaxes(quat_xyzw_to_rot(q[first[ok]]), 1, 2) @ quat_xyzw_to_rot(q[last[ok]])
    turn, err = _angle(gyro_rel), _angle(np.swapaxes(ori_rel, 1, 2) @ gyro_rel)
    judged = ~gap & ok & (turn >= MIN_TURN_RAD)
    if not np.any(judged):
        return OrientationCheck(valid, 0, 0, float("nan"), float("nan"))
    bad = err[judged] > AGREE_RAD + AGREE_SHARE * turn[judged]
    return OrientationCheck(valid, int(judged.sum()), int(bad.sum()), float(np.median(err[judged])),
                            float(np.median(turn[judged])))
