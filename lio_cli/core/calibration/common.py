"""What every calibration estimator shares: input checks that fail with one readable line, the result base
class, and a covariance that survives overlapping windows.

Inputs are the arrays ``lio calibrate`` reads from a log: a LiDAR odometry trajectory (``stamps_ns`` int64,
``T_world_lidar`` (N,4,4)) and raw IMU samples (``stamps_ns`` int64, ``gyro_radps``/``accel_mps2`` (M,3) in
the IMU frame). Times are int64 ns; float seconds appear only relative to a reference stamp.
"""

from __future__ import annotations

from dataclasses import dataclass, fields

import numpy as np

from ...errors import InputError

NS_PER_S = 1_000_000_000


@dataclass(frozen=True, eq=False)
class CalibrationResult:
    """Base of every estimator's result: ``notes`` say what was skipped, assumed or found, and why."""

    def to_dict(self) -> dict:
        """Plain Python values (lists, floats, ints, str, None), ready for JSON or YAML."""
        return {f.name: _plain(getattr(self, f.name)) for f in fields(self)}


def _plain(v):
    if isinstance(v, np.ndarray):
        return v.tolist()
    if isinstance(v, np.generic):
        return v.item()
    if isinstance(v, CalibrationResult):
        return v.to_dict()
    if isinstance(v, (tuple, list)):
        return [_plain(x) for x in v]
    if isinstance(v, dict):
        return {k: _plain(x) for k, x in v.items()}
    return v


def check_stamps(stamps_ns: np.ndarray, what: str, min_count: int = 2) -> np.ndarray:
    """int64 stamps, strictly increasing, at least ``min_count`` of them."""
    s = np.asarray(stamps_ns)
    if s.ndim != 1 or len(s) < min_count:
        raise InputError(f"{what}: needs at least {min_count} stamps (got {s.size})")
    if not np.issubdtype(s.dtype, np.integer):
        raise InputError(f"{what}: stamps must be integer nanoseconds (got {s.dtype})")
    s = s.astype(np.int64)
    d = np.diff(s)
    if (d <= 0).any():
        k = int(np.argmax(d <= 0)) + 1
        raise InputError(f"{what}: stamps must be strictly increasing (sample {k} is {-d[k - 1] / 1e6:.3f} ms "
                         f"behind the one before)")
    return s


def check_vectors(values: np.ndarray, n: int, what: str, width: int = 3) -> np.ndarray:
    """(n, width) finite float64 values."""
    v = np.asarray(values, dtype=np.float64)
    if v.shape != (n, width):
        raise InputError(f"{what}: expected shape ({n}, {width}), got {v.shape}")
    bad = int((~np.isfinite(v)).any(axis=1).sum())
    if bad:
        raise InputError(f"{what}: {bad} of {n} samples hold NaN or infinite values")
    return v


def check_imu(stamps_ns: np.ndarray, gyro_radps: np.ndarray | None, accel_mps2: np.ndarray | None = None,
              min_count: int = 2) -> tuple[np.ndarray, np.ndarray | None, np.ndarray | None]:
    """Validated (stamps, gyro, accel) of raw IMU samples; either array may be None when not needed."""
    if stamps_ns is None or len(stamps_ns) == 0:
        raise InputError("no IMU samples")
    s = check_stamps(stamps_ns, "IMU", min_count)
    g = None if gyro_radps is None else check_vectors(gyro_radps, len(s), "IMU gyro")
    a = None if accel_mps2 is None else check_vectors(accel_mps2, len(s), "IMU accelerometer")
    return s, g, a


def check_trajectory(stamps_ns: np.ndarray, poses: np.ndarray, what: str = "LiDAR trajectory",
                     min_count: int = 3) -> tuple[np.ndarray, np.ndarray]:
    """Validated (stamps, poses (N,4,4)) with orthonormal rotation blocks."""
    s = check_stamps(stamps_ns, what, min_count)
    P = np.asarray(poses, dtype=np.float64)
    if P.shape != (len(s), 4, 4):
        raise InputError(f"{what}: expected poses of shape ({len(s)}, 4, 4), got {P.shape}")
    if not np.isfinite(P).all():
        raise InputError(f"{what}: poses hold NaN or infinite values")
    R = P[:, :3, :3]
    err = np.abs(np.einsum("nji,njk->nik", R, R) - np.eye(3)).max(axis=(1, 2))
    if (err > 1e-3).any():
        raise InputError(f"{what}: pose {int(np.argmax(err > 1e-3))} has a rotation block that is not orthonormal")
    return s, P


def check_overlap(imu_stamps_ns: np.ndarray, traj_stamps_ns: np.ndarray, imu_time_offset_s: float,
                  min_overlap_s: float = 2.0) -> None:
    """Raise a clock-mismatch InputError when the IMU (shifted onto the LiDAR clock) and the trajectory
    share less than ``min_overlap_s``."""
    off_ns = int(round(imu_time_offset_s * NS_PER_S))
    i0, i1 = int(imu_stamps_ns[0]) + off_ns, int(imu_stamps_ns[-1]) + off_ns
    t0, t1 = int(traj_stamps_ns[0]), int(traj_stamps_ns[-1])
    overlap_s = (min(i1, t1) - max(i0, t0)) / NS_PER_S
    if overlap_s < min_overlap_s and overlap_s >= min(i1 - i0, t1 - t0) / NS_PER_S - 0.2:
        # the shorter of the two lies within the other (give or take a scan): the log is short, not the clocks off
        raise InputError(f"too short: the IMU and the LiDAR trajectory share {max(overlap_s, 0.0):.1f} s (need "
                         f"{min_overlap_s:g} s): record longer")
    if overlap_s < min_overlap_s:
        gap_s = (t0 - i0) / NS_PER_S
        raise InputError(f"clock mismatch: the IMU and the LiDAR share {max(overlap_s, 0.0):.1f} s of time "
                         f"(need {min_overlap_s:g} s; LiDAR starts {gap_s:+.3f} s from the IMU): are they stamped "
                         f"by different clocks?")


def sandwich_covariance(H: np.ndarray, scores: np.ndarray, lag: int, prior_info: np.ndarray | None = None) -> np.ndarray:
    """Covariance of a least-squares estimate whose per-window scores ``J_i^T r_i`` (n, p) are correlated
    over ``lag`` neighbouring windows (overlapping windows share poses): H^-1 S H^-1 with the Newey-West
    (Bartlett) estimate of S. ``H`` is the full normal matrix (with any prior); ``prior_info`` the prior's
    part of it, whose scores are not in ``scores``."""
    S = scores.T @ scores
    for k in range(1, lag + 1):
        w = 1.0 - k / (lag + 1.0)
        C = scores[k:].T @ scores[:-k]
        S += w * (C + C.T)
    if prior_info is not None:
        S = S + prior_info
    try:  # not pinv: its relative cutoff would zero well-posed but small blocks beside huge ones
        Hi = np.linalg.inv(H)
    except np.linalg.LinAlgError:
        Hi = np.linalg.pinv(H)
    return Hi @ S @ Hi


def outliers_3d(norms: np.ndarray, floor: float, sigmas: float = 5.0) -> np.ndarray:
    """Mask of 3-vector residuals whose norm exceeds ``sigmas`` per-axis sigmas, the sigma read robustly from the
    median norm (a 3-D Gaussian's norm has median 1.538 sigma) but never below ``floor`` (noise-free data)."""
    return norms > sigmas * max(float(np.median(norms)) / 1.5382, floor)


def time_ranges_text(stamps_ns: np.ndarray, mask: np.ndarray, t0_ns: int, limit: int = 4, join_ns: int = 0) -> str:
    """'2.0-5.5 s, 7.1-9.0 s' for the runs where ``mask`` holds, in seconds after ``t0_ns``. Runs apart by less
    than ``join_ns`` (from the last sample of one to the first of the next) are given as one."""
    runs = true_runs(mask)
    joined: list[tuple[int, int]] = []
    for a, b in runs:
        if joined and stamps_ns[a] - stamps_ns[joined[-1][1] - 1] < join_ns:
            joined[-1] = (joined[-1][0], b)
        else:
            joined.append((a, b))
    runs = joined
    parts = [f"{(stamps_ns[a] - t0_ns) / NS_PER_S:.1f}-{(stamps_ns[b - 1] - t0_ns) / NS_PER_S:.1f} s" for a, b in runs[:limit]]
    if len(runs) > limit:
        parts.append(f"and {len(runs) - limit} more")
    return ", ".join(parts)


def true_runs(mask: np.ndarray) -> list[tuple[int, int]]:
    """[(start, stop)) index ranges of the runs of True in ``mask``."""
    m = np.concatenate([[False], np.asarray(mask, bool), [False]])
    edges = np.flatnonzero(np.diff(m.astype(np.int8)))
    return [(int(a), int(b)) for a, b in zip(edges[::2], edges[1::2])]
