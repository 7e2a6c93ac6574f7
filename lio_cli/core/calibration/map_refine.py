"""Sharper LiDAR poses for the calibration: every scan registered point-to-plane against one map of all scans.

The scan-to-local-map registration of odometry (kiss-icp, point-to-point) on a sparse scanner scatters roll and
pitch from scan to scan: its map is the last few scans, each placed with the same scatter, and its point pairs
are of rings that never coincide. The rotation increments the hand-eye fit reads are then mostly that scatter.
Here the whole log's scans, de-skewed with the gyro through the current mounting estimate, form one map; planes
fitted to its voxels average many scans, and every scan is registered point-to-plane against them. What is left
is the map's own blur and the de-skew, so the caller re-estimates the mounting between rounds (map, register,
again) and each round de-skews with a better one.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ...geometry import cross_rows, so3_exp
from ..kdtree import ckdtree_class
from ..deskew.voxel_map import voxel_keys
from .signals import GyroOrientation

NEIGHBOURS = 10  # map points per local plane
FLATNESS = 0.05  # a plane: smallest eigenvalue below this share of the middle one
ITERATIONS = 4
SOURCE_STRIDE = 2  # every other point of a scan is registered (the map has them all)
MIN_PAIRS = 50  # fewer paired points: the scan keeps its pose
MAX_STEP_RAD, MAX_STEP_M = 0.05, 0.2  # a larger correction in one iteration: the scan keeps its pose
VELOCITY_HALF_SPAN = 1  # scans either side of one whose pose difference de-skews its translation (_velocities)


@dataclass(frozen=True)
class Sweep:
    """A thinned scan: points in the LiDAR frame at their own capture, and their times."""

    end_ns: int
    points: np.ndarray  # (M,3) float32
    dt_s: np.ndarray  # (M,) float32: capture time minus ``end_ns`` (<= 0 for a scan stamped at its end)


def thin_sweep(points: np.ndarray, stamps_ns: np.ndarray, end_ns: int, voxel_m: float) -> Sweep:
    """One point per ``voxel_m`` cube (the first in firing order), with its time."""
    keys, inside = voxel_keys(np.asarray(points, np.float64), voxel_m)
    _, first = np.unique(keys[inside], return_index=True)
    first = np.flatnonzero(inside)[np.sort(first)]
    return Sweep(int(end_ns), np.asarray(points[first], np.float32),
                 ((np.asarray(stamps_ns, np.int64)[first] - int(end_ns)) * 1e-9).astype(np.float32))


def _deskewed(sweep: Sweep, gyro: GyroOrientation, R_lidar_imu: np.ndarray, offset_s: float,
              v_lidar: np.ndarray) -> np.ndarray:
    """The sweep's points in the LiDAR frame at its end: the gyro's rotation through the mounting, the
    translation at ``v_lidar`` (the LiDAR's velocity in its end frame). One sweep at a time, so its arrays stay
    in the cache."""
    te = gyro.relative_s(np.array([sweep.end_ns], np.int64), offset_s)
    dt = sweep.dt_s.astype(np.float64)
    in_imu = gyro.rotate(te[0] + dt, sweep.points.astype(np.float64) @ R_lidar_imu)  # the IMU's start frame
    return (in_imu @ gyro.at(te)[0]) @ R_lidar_imu.T + dt[:, None] * v_lidar


def _velocities(stamps_ns: np.ndarray, poses: np.ndarray, half: int = VELOCITY_HALF_SPAN) -> np.ndarray:
    """The LiDAR's velocity in its own frame over each scan: the difference of the poses ``half`` + 1 before and
    ``half`` after it, centred on the scan's middle (``half`` = 0: the step before; the ends take what there is).
    Several intervals keep two poses' noise over one short step out of every de-skew; a walk's steps are still
    followed."""
    n = len(poses)
    k = np.arange(n)
    lo, hi = np.clip(k - 1 - half, 0, n - 1), np.clip(k + half, 0, n - 1)
    hi = np.where(hi == lo, np.minimum(hi + 1, n - 1), hi)
    t = np.asarray(stamps_ns, np.int64)
    v = (poses[hi, :3, 3] - poses[lo, :3, 3]) / ((t[hi] - t[lo]) * 1e-9)[:, None]
    return np.einsum("nji,nj->ni", poses[:, :3, :3], v)


class PlaneMap:
    """Voxel means of world points, each with the plane of its ``NEIGHBOURS`` nearest (centroid, normal); a
    scan point is paired with the plane of the voxel it falls in (a hash lookup, cheaper than a k-d tree query
    per point)."""

    def __init__(self, world: np.ndarray, voxel_m: float) -> None:
        keys, inside = voxel_keys(world, voxel_m)
        world = world[inside]
        self.keys, inv, count = np.unique(keys[inside], return_inverse=True, return_counts=True)
        self.voxel_m = voxel_m
        pts = np.stack([np.bincount(inv, world[:, d], len(count)) for d in range(3)], axis=1) / count[:, None]
        self.tree = ckdtree_class()(pts)
        _, nn = self.tree.query(pts, k=min(NEIGHBOURS, len(pts)), workers=-1)
        nb = pts[nn]
        self.centroid = nb.mean(axis=1)
        c = nb - self.centroid[:, None]
        w, v = np.linalg.eigh(np.einsum("nki,nkj->nij", c, c))
        self.normal = v[:, :, 0]
        self.offset = np.einsum("ni,ni->n", self.normal, self.centroid)  # the plane: n . x = offset
        self.flat = w[:, 0] < FLATNESS * w[:, 1]

    def register(self, srcs: list[np.ndarray], T: np.ndarray) -> np.ndarray:
        """Each T_world_lidar (n,4,4) placing its source ``srcs[i]`` (LiDAR frame) on the planes, from ``T``; NaN
        where it cannot (too few pairs, or too large a step). All scans at once, each on its own: per scan,
        Gauss-Newton with Huber weights at two of its robust residual sigmas."""
        T = np.array(T, np.float64)
        n = len(srcs)
        sid_all = np.repeat(np.arange(n), [len(p) for p in srcs])
        P_all = np.concatenate(srcs).astype(np.float64)
        alive = np.ones(n, bool)
        for _ in range(ITERATIONS):
            use = alive[sid_all]
            sid, P = sid_all[use], P_all[use]
            q = np.einsum("nij,nj->ni", T[sid, :3, :3], P) + T[sid, :3, 3]
            k, inside = voxel_keys(q, self.voxel_m)  # paired with the plane of the map voxel it falls in
            nn = np.minimum(np.searchsorted(self.keys, k), len(self.keys) - 1)
            ok = (self.keys[nn] == k) & self.flat[nn] & inside
            alive &= np.bincount(sid[ok], minlength=n) >= MIN_PAIRS
            ok &= alive[sid]
            if not ok.any():
                break
            q, j, sid = q[ok], nn[ok], sid[ok]
            nrm = self.normal[j]
            r = np.einsum("ni,ni->n", nrm, q) - self.offset[j]
            J = np.concatenate([cross_rows(q, nrm), nrm], axis=1)  # d r / d(rotation, translation), left perturbation
            scale = 1.4826 * _group_medians(np.abs(r), sid, n)[sid] + 1e-4
            w = 1.0 / np.maximum(1.0, np.abs(r) / (2.0 * scale))  # Huber at two robust sigmas
            Jw = J * w[:, None]
            H = np.empty((n, 6, 6))
            for a in range(6):
                for b in range(a + 1):
                    H[:, a, b] = H[:, b, a] = np.bincount(sid, Jw[:, a] * J[:, b], minlength=n)
            g = np.stack([np.bincount(sid, Jw[:, a] * r, minlength=n) for a in range(6)], axis=1)
            idx = np.flatnonzero(alive)
            step = -np.linalg.solve(H[idx] + 1e-9 * np.eye(6), g[idx][:, :, None])[:, :, 0]
            big = (np.linalg.norm(step[:, :3], axis=1) > MAX_STEP_RAD) | (np.linalg.norm(step[:, 3:], axis=1) > MAX_STEP_M)
            alive[idx[big]] = False
            idx, step = idx[~big], step[~big]
            dT = np.tile(np.eye(4), (len(idx), 1, 1))
            dT[:, :3, :3] = so3_exp(step[:, :3])
            dT[:, :3, 3] = step[:, 3:]
            T[idx] = dT @ T[idx]
        T[~alive] = np.nan
        return T


def _group_medians(x: np.ndarray, group: np.ndarray, n: int) -> np.ndarray:
    """Median of ``x`` within each of ``n`` groups (``group`` sorted ascending; empty groups: NaN)."""
    count = np.bincount(group, minlength=n)
    start = np.concatenate([[0], np.cumsum(count)[:-1]])
    rows = np.full((n, max(int(count.max()), 1)), np.inf)
    rows[group, np.arange(len(x)) - start[group]] = x
    rows.sort(axis=1)
    lo, hi = np.maximum((count - 1) // 2, 0), np.maximum(count // 2, 0)
    ar = np.arange(n)
    return np.where(count > 0, 0.5 * (rows[ar, lo] + rows[ar, hi]), np.nan)


def refine_poses(stamps_ns: np.ndarray, T_world_lidar: np.ndarray, sweeps: dict[int, Sweep], gyro: GyroOrientation,
                 R_lidar_imu: np.ndarray, imu_time_offset_s: float, map_voxel_m: float) -> tuple[np.ndarray, int]:
    """One round: every pose with a sweep (keyed by its stamp) re-registered against the map of all of them,
    de-skewed through ``R_lidar_imu`` and the clock offset. Returns the poses and how many were moved."""
    poses = np.array(T_world_lidar, np.float64)
    idx = [k for k, s in enumerate(stamps_ns) if int(s) in sweeps]
    if len(poses) < 2 or not idx:
        return poses, 0
    v = _velocities(np.asarray(stamps_ns, np.int64), poses)
    src = {k: _deskewed(sweeps[int(stamps_ns[k])], gyro, R_lidar_imu, imu_time_offset_s, v[k]) for k in idx}
    world = np.concatenate([src[k] @ poses[k, :3, :3].T + poses[k, :3, 3] for k in idx])
    planes = PlaneMap(world, map_voxel_m)
    T = planes.register([src[k][::SOURCE_STRIDE] for k in idx], poses[idx])
    moved = np.isfinite(T[:, 0, 0])
    poses[np.asarray(idx)[moved]] = T[moved]
    return poses, int(moved.sum())
