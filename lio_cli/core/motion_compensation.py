"""Per-point motion compensation (de-skewing).

Each point was measured from the sensor pose at its own stamp. Given the base trajectory over the scan
(``T_world_base`` at knot stamps), every point is moved into the base frame at the reference instant:
``p_base_ref = T_world_base(t_ref)^-1 T_world_base(t_j) T_base_lidar p_lidar``.
Only the motion within the scan matters, so a constant error in the trajectory cancels.
"""

from __future__ import annotations

import numpy as np

from ..geometry import interpolate_poses, inv_pose


def deskew(points_lidar: np.ndarray, stamps_ns: np.ndarray, knot_stamps_ns: np.ndarray, knot_poses: np.ndarray,
           t_ref_ns: int, T_base_lidar: np.ndarray) -> np.ndarray:
    """Points (N,3) in the base frame at ``t_ref_ns``, each corrected for the motion since its stamp.

    Within one knot interval (an IMU period, a few ms) the pose is blended linearly between the two knots'
    relative poses; the chord-for-arc error of that blend is below a millimetre at 30 m for 3 rad/s.
    """
    knot_stamps_ns = np.asarray(knot_stamps_ns, dtype=np.int64)
    ref = interpolate_poses(knot_stamps_ns, knot_poses, np.array([t_ref_ns]))[0]
    rel = inv_pose(ref)[None] @ knot_poses @ T_base_lidar  # T_base(ref)_lidar(knot): lidar points in one step
    m = len(knot_stamps_ns)
    if m == 1:
        return points_lidar @ rel[0, :3, :3].T + rel[0, :3, 3]
    idx = np.searchsorted(knot_stamps_ns, stamps_ns, side="right") - 1
    np.clip(idx, 0, m - 2, out=idx)
    span = np.maximum(np.diff(knot_stamps_ns), 1).astype(np.float64)
    a = (stamps_ns - knot_stamps_ns[idx]) / span[idx]
    np.clip(a, 0.0, 1.0, out=a)
    # spinning LiDARs deliver points in firing order: then every interval is a contiguous slice
    order = None if np.all(idx[1:] >= idx[:-1]) else np.argsort(idx, kind="stable")
    sorted_idx = idx if order is None else idx[order]
    bounds = np.searchsorted(sorted_idx, np.arange(m))
    out = np.empty_like(points_lidar, dtype=np.float64)
    for k in range(m - 1):
        lo, hi = bounds[k], bounds[k + 1]
        if hi <= lo:
            continue
        sel = slice(lo, hi) if order is None else order[lo:hi]
        q = points_lidar[sel]
        q0 = q @ rel[k, :3, :3].T + rel[k, :3, 3]
        q1 = q @ rel[k + 1, :3, :3].T + rel[k + 1, :3, 3]
        q1 -= q0
        q1 *= a[sel, None]
        q1 += q0
        out[sel] = q1
    return out


def to_base(points_lidar: np.ndarray, T_base_lidar: np.ndarray) -> np.ndarray:
    """No motion compensation: points just moved into the base frame."""
    return points_lidar @ T_base_lidar[:3, :3].T + T_base_lidar[:3, 3]


def constant_velocity_knots(delta: np.ndarray, t_prev_ns: int, t_ref_ns: int) -> tuple[np.ndarray, np.ndarray]:
    """Knots for de-skewing with the last inter-scan motion ``delta`` = T_base(prev)_base(ref) (relative poses).

    A zero-length interval (the first scan, or every point at the header stamp) has nothing to blend: one knot
    at ``t_ref_ns`` holding ``delta``, so no pose is interpolated over a span of 0 ns."""
    if t_ref_ns <= t_prev_ns:
        return np.array([t_ref_ns], dtype=np.int64), np.asarray(delta, dtype=np.float64)[None].copy()
    return np.array([t_prev_ns, t_ref_ns], dtype=np.int64), np.stack([np.eye(4), delta])
