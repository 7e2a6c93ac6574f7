"""LiDAR-IMU time offset: when do the gyro's rotations line up with the LiDAR trajectory's?

Coarse: over a grid of offsets, the gyro's mean turn rate over each scan interval is aligned with the LiDAR's
rotation increments by the best rotation (Kabsch); the score is how much of the rotation the alignment
explains. This uses the whole rotation vector, not only the angular speed, so the aliases a back-and-forth
sweep makes in the speed (every half period) do not win. Fine: Brent's method on the same cost with the gyro
integrated exactly (trapezoid, interpolated) and a gyro bias fitted alongside; outlying scan intervals (a bad
registration) are left out and the fit repeated. The 1-sigma comes from the Jacobian of the residuals in
offset, rotation and bias, with neighbouring intervals' correlation (they share a pose) accounted for.

Sign convention (DESIGN.md): ``imu_time_offset_s`` is ADDED to IMU stamps to put them on the LiDAR's clock.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ...errors import InputError
from ...geometry import skew
from ...minimize import minimize_bounded
from .common import (NS_PER_S, CalibrationResult, check_imu, check_overlap, check_trajectory, outliers_3d,
                     sandwich_covariance)
from .handeye import align, imu_increments, interval_pairs, keep_finite_increments, lidar_increments
from .signals import GyroOrientation, PiecewiseLinear

MIN_PEAK_RATE_RADPS = np.radians(10.0)
MIN_ALIGNMENT = 0.5
WEAK_SIGMA_S = 0.001
OUTLIER_FLOOR_RAD = 1e-4  # residual sigma below which nothing is an outlier
GRID_BLOCK_ROWS = 200_000  # offsets x intervals per batched block of the coarse grid: ~50 MB of temporaries
MOVE_HINT = ("swing the sensor back and forth (yaw or roll sweeps of +-30 deg at about 1 Hz) for 10-20 s; on a vehicle, "
             "drive a slalom")


@dataclass(frozen=True, eq=False)
class TimeOffset(CalibrationResult):
    imu_time_offset_s: float  # t_lidar = t_imu_stamp + offset
    sigma_s: float  # 1-sigma
    alignment: float  # share of the rotation the best alignment explains at the coarse peak (1 = all)
    R_lidar_imu: np.ndarray  # the rotation found alongside (rotation.py refines it)
    gyro_bias_radps: np.ndarray  # bias used: the given one plus the correction fitted here
    intervals: int  # scan intervals used
    rms_residual_rad: float
    notes: tuple[str, ...]


def estimate_time_offset(lidar_stamps_ns: np.ndarray, T_world_lidar: np.ndarray, imu_stamps_ns: np.ndarray,
                         gyro_radps: np.ndarray, *, gyro_bias_radps: np.ndarray | None = None,
                         max_offset_s: float = 0.5, coarse_step_s: float = 0.002,
                         max_sigma_s: float = 0.005) -> TimeOffset:
    """Time offset of the IMU against a LiDAR odometry trajectory (poses T_world_lidar at the scan stamps).

    ``gyro_bias_radps``: a known bias (e.g. from the still stretch) to start from; a correction is fitted.
    ``max_offset_s`` bounds the search (either sign); a 1-sigma above ``max_sigma_s`` means the motion does not
    pin the offset: an InputError that says how to move (above 1 ms: a note)."""
    ls, poses = check_trajectory(lidar_stamps_ns, T_world_lidar)
    istamps, gyro, _ = check_imu(imu_stamps_ns, gyro_radps)
    check_overlap(istamps, ls, 0.0, min_overlap_s=2.0 + 2 * max_offset_s)
    bias0 = np.zeros(3) if gyro_bias_radps is None else np.asarray(gyro_bias_radps, np.float64)
    notes: list[str] = []

    ia, ib = interval_pairs(ls, 1)
    # intervals the IMU covers whatever the offset in the search range
    lo, hi = istamps[0] + max_offset_s * NS_PER_S, istamps[-1] - max_offset_s * NS_PER_S
    ia, ib = ia[(ls[ia] >= lo) & (ls[ib] <= hi)], ib[(ls[ia] >= lo) & (ls[ib] <= hi)]
    phi_l = lidar_increments(poses, ia, ib)
    ok = keep_finite_increments(phi_l)
    ia, ib, phi_l = ia[ok], ib[ok], phi_l[ok]
    if len(ia) < 20:
        raise InputError(f"time offset: only {len(ia)} LiDAR scan intervals overlap the IMU data (need 20)")
    ta, tb = ls[ia], ls[ib]
    dt = (tb - ta) / NS_PER_S
    rate = np.linalg.norm(phi_l, axis=1) / dt
    if np.percentile(rate, 95) < MIN_PEAK_RATE_RADPS:
        raise InputError(f"too little rotation to time the IMU against the LiDAR: the trajectory turns at most "
                         f"{np.degrees(np.percentile(rate, 95)):.1f} deg/s; {MOVE_HINT}")

    # coarse: best-rotation alignment of mean gyro rates over a grid of offsets
    pl = PiecewiseLinear((istamps - istamps[0]) / NS_PER_S, gyro - bias0)
    t_a, t_b = (ta - istamps[0]) / NS_PER_S, (tb - istamps[0]) / NS_PER_S
    grid = np.arange(-max_offset_s, max_offset_s + 0.5 * coarse_step_s, coarse_step_s)
    score = _alignments(phi_l, pl, t_a, t_b, dt, grid)
    k = int(np.argmax(score))
    if k in (0, len(grid) - 1):
        raise InputError(f"the IMU-LiDAR time offset lies beyond the +-{max_offset_s:g} s searched (best at the edge): "
                         f"a clock mismatch between the sensors?")
    if score[k] < MIN_ALIGNMENT:
        raise InputError(f"the gyro's rotations do not match the LiDAR trajectory's at any offset within "
                         f"+-{max_offset_s:g} s (best alignment {score[k]:.2f}): wrong IMU topic, or a trajectory of "
                         f"another sensor?")
    _note_aliases(grid, score, k, notes)

    gyro_int = GyroOrientation(istamps, gyro, bias0)
    keep = np.ones(len(ia), bool)
    for attempt in range(2):
        cost = _Cost(gyro_int, ta[keep], tb[keep], dt[keep], phi_l[keep])
        off, _ = minimize_bounded(cost, grid[k] - 2 * coarse_step_s, grid[k] + 2 * coarse_step_s, xatol=1e-6)
        R, b, r = cost.solve(off)
        bad = outliers_3d(np.linalg.norm(r, axis=1), OUTLIER_FLOOR_RAD)
        if attempt == 1 or not bad.any():
            break
        keep[np.flatnonzero(keep)[bad]] = False
        n = int(bad.sum())
        notes.append(f"{n} scan interval{'s' * (n != 1)} left out: {'their' if n != 1 else 'its'} rotation "
                     "disagrees with the gyro's (bad registrations?)")
    sigma = _offset_sigma(cost, off, R, b, r)
    if sigma > max_sigma_s:
        raise InputError(f"too little change in rotation to time the IMU against the LiDAR (1-sigma "
                         f"{sigma * 1e3:.1f} ms; its turn rate never changes faster than "
                         f"{np.degrees(_rate_change(ta, phi_l)):.0f} deg/s^2 over a second): {MOVE_HINT}")
    if sigma > WEAK_SIGMA_S:
        notes.append(f"the offset is weakly determined (1-sigma {sigma * 1e3:.1f} ms): {MOVE_HINT}")
    return TimeOffset(off, sigma, float(score[k]), R, bias0 + b, int(keep.sum()),
                      float(np.sqrt((r * r).mean())), tuple(notes))


def _rate_change(ta: np.ndarray, phi_l: np.ndarray, window_s: float = 1.0) -> float:
    """The 95th percentile of how fast the LiDAR's turn rate (averaged over ``window_s``) changes, rad/s^2."""
    k = np.floor((ta - ta[0]) / (window_s * NS_PER_S)).astype(int)
    counts = np.bincount(k)
    full = counts > 0
    turned = np.stack([np.bincount(k, phi_l[:, i], len(counts)) for i in range(3)], axis=1)[full]
    rate = turned / window_s  # rad/s, each window's mean (intervals of one scan cover it)
    if len(rate) < 2:
        return 0.0
    return float(np.percentile(np.linalg.norm(np.diff(rate, axis=0), axis=1) / window_s, 95))


def _alignments(phi_l: np.ndarray, pl: PiecewiseLinear, t_a: np.ndarray, t_b: np.ndarray, dt: np.ndarray,
                grid: np.ndarray) -> np.ndarray:
    """For each offset of ``grid``, how well one rotation maps the gyro's mean rates shifted by it (``phi_i``) onto
    the LiDAR's (``phi_l``): 1 - min_R sum |phi_l - R phi_i|^2 / sum (|phi_l|^2 + |phi_i|^2), 1 when one rotation
    explains all. One 3x3 product and SVD per offset as batched calls, in blocks of offsets so memory stays linear
    in the log whatever the grid."""
    n = len(t_a)
    block = max(1, GRID_BLOCK_ROWS // max(n, 1))
    out = []
    for i in range(0, len(grid), block):
        sub = grid[i:i + block]
        g, shift = len(sub), np.repeat(sub, n)
        phi_i = (pl.interval_mean(np.tile(t_a, g) - shift, np.tile(t_b, g) - shift)
                 * np.tile(dt, g)[:, None]).reshape(g, n, 3)
        s = np.linalg.svd(np.swapaxes(phi_i, 1, 2) @ phi_l, compute_uv=False)
        out.append(2.0 * s.sum(axis=1) / ((phi_l**2).sum() + (phi_i**2).sum(axis=(1, 2))))
    return np.concatenate(out)


def _note_aliases(grid: np.ndarray, score: np.ndarray, k: int, notes: list[str]) -> None:
    far = np.abs(grid - grid[k]) > 0.05
    if far.any() and score[far].max() > score[k] - 0.02:
        j = int(np.flatnonzero(far)[np.argmax(score[far])])
        notes.append(f"another offset ({grid[j] * 1e3:+.0f} ms) aligns nearly as well as the one found "
                     f"({grid[k] * 1e3:+.0f} ms): the motion is very periodic; vary it if the result looks wrong")


class _Cost:
    """Sum of squared residuals |phi_lidar - R (phi_imu(offset) - b dt)|^2 with R and b at their best."""

    def __init__(self, gyro: GyroOrientation, ta: np.ndarray, tb: np.ndarray, dt: np.ndarray, phi_l: np.ndarray) -> None:
        self.gyro, self.ta, self.tb, self.dt, self.phi_l = gyro, ta, tb, dt, phi_l

    def phi_imu(self, off: float) -> np.ndarray:
        return imu_increments(self.gyro, self.ta, self.tb, off)

    def solve(self, off: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        return align(self.phi_l, self.phi_imu(off), self.dt)

    def __call__(self, off: float) -> float:
        _, _, r = self.solve(off)
        return float((r * r).sum())


def _offset_sigma(cost: _Cost, off: float, R: np.ndarray, b: np.ndarray, r: np.ndarray) -> float:
    """1-sigma of the offset with rotation and bias as nuisance; neighbouring intervals share a pose."""
    h = 1e-4
    d_off = -((cost.phi_imu(off + h) - cost.phi_imu(off - h)) / (2 * h)) @ R.T  # d r / d offset
    u = (cost.phi_imu(off) - b * cost.dt[:, None]) @ R.T
    J = np.concatenate([d_off[:, :, None], skew(u), np.broadcast_to(R, (len(u), 3, 3)) * cost.dt[:, None, None]], axis=2)
    H = np.einsum("nji,njk->ik", J, J)
    scores = np.einsum("nji,nj->ni", J, r)
    return float(np.sqrt(sandwich_covariance(H, scores, lag=1)[0, 0]))


