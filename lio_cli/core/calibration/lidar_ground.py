"""The ground's normal in the LiDAR frame from scans taken while the platform stood still (GRIL-Calib's ground
constraint).

A vehicle standing on level ground sees the ground below it as a plane whose normal is the world's up; the
accelerometer at rest sees the same up through gravity, so the pair fixes the IMU's roll and pitch in the
LiDAR frame (``R_lidar_imu up_imu = n_lidar``) without any motion. The plane is found by RANSAC among the
points below the sensor whose heights (along a guess of up, e.g. from the LiDAR's drawing on the base) are
near the lowest, refined by least squares on its inliers. Its 1-sigma adds to the least-squares one the scatter
of the normals of azimuth sectors fitted alone: on uneven ground the one plane's tilt is as uncertain as the
ground's own tilt varies around the vehicle.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ...errors import InputError
from ...geometry import axes_across
from .common import CalibrationResult

MAX_TILT_RAD = np.radians(20.0)  # the ground's normal within this of the up guessed
MIN_RANGE_M, MAX_RANGE_M = 2.0, 40.0  # horizontal distance of the points used (the car's body, sparse far rings)
INLIER_M = 0.08  # RANSAC's distance to the plane of an inlier
MIN_INLIERS = 200
SECTORS = 8  # azimuth sectors whose normals' scatter joins the 1-sigma
MIN_SECTOR_POINTS = 30
MAX_POINTS = 20000  # points sampled for RANSAC (three times as many at most for the refinement)
RANSAC_TRIALS = 200


@dataclass(frozen=True, eq=False)
class LidarGround(CalibrationResult):
    normal: np.ndarray  # (3,) unit, the ground's up in the LiDAR frame
    covariance_rad2: np.ndarray  # (3,3) of a small rotation of ``normal`` (rank 2: nothing about the normal)
    sigma_rad: float  # the larger 1-sigma of the normal's tilt
    height_m: float  # the LiDAR origin's height above the plane
    inliers: int
    rms_m: float  # of the inliers' distances to the plane
    sectors: int  # azimuth sectors in the scatter
    notes: tuple[str, ...]


def fit_lidar_ground(points: np.ndarray, up_guess: np.ndarray, seed: int = 0) -> LidarGround:
    """The ground plane under the LiDAR from ``points`` (N,3, LiDAR frame, scans of a platform at rest stacked)
    and ``up_guess`` (the LiDAR frame's up as drawn). InputError when no plane within ``MAX_TILT_RAD`` of the
    guess holds ``MIN_INLIERS`` points (a 2D scanner, a LiDAR that does not see the ground)."""
    p = np.asarray(points, float).reshape(-1, 3)
    p = p[np.isfinite(p).all(axis=1)]
    up = np.asarray(up_guess, float) / np.linalg.norm(up_guess)
    h = p @ up
    horiz = np.linalg.norm(p - np.outer(h, up), axis=1)
    cand = p[(h < -0.2) & (horiz > MIN_RANGE_M) & (horiz < MAX_RANGE_M)]
    if len(cand) < MIN_INLIERS:
        raise InputError(f"ground plane: {len(cand)} points below the LiDAR within {MAX_RANGE_M:g} m (need "
                         f"{MIN_INLIERS}): the scans do not show the ground")
    rng = np.random.default_rng(seed)
    if len(cand) > 3 * MAX_POINTS:  # a few scans' worth: more only costs time
        cand = cand[rng.choice(len(cand), 3 * MAX_POINTS, replace=False)]
    sample = cand if len(cand) <= MAX_POINTS else cand[rng.choice(len(cand), MAX_POINTS, replace=False)]
    low = sample[sample @ up <= np.quantile(sample @ up, 0.5)]  # the plane's hypotheses from the lower half
    best, best_n = None, 0
    for _ in range(RANSAC_TRIALS):
        a, b, c = low[rng.choice(len(low), 3, replace=False)]
        n = np.cross(b - a, c - a)
        norm = np.linalg.norm(n)
        if norm < 1e-9:
            continue
        n = n / norm
        if n @ up < 0:
            n = -n
        if np.arccos(np.clip(n @ up, -1, 1)) > MAX_TILT_RAD:
            continue
        count = int((np.abs((sample - a) @ n) < INLIER_M).sum())
        if count > best_n:
            best, best_n = (n, float(a @ n)), count
    if best is None or best_n < MIN_INLIERS:
        raise InputError(f"ground plane: no plane within {np.degrees(MAX_TILT_RAD):.0f} deg of level holds "
                         f"{MIN_INLIERS} points (best {best_n})")
    n, d = best
    for tol in (INLIER_M, None):  # least squares on the inliers, then on those within 3 rms of it
        dist = cand @ n - d
        if tol is None:
            tol = max(3.0 * float(np.sqrt(np.mean(dist[inl] ** 2))), 0.01)
        inl = np.abs(dist) < tol
        n, d = _plane(cand[inl], up)
    pts = cand[inl]
    resid = pts @ n - d
    rms = float(np.sqrt(np.mean(resid**2)))
    C = _ls_covariance(pts, n, rms)
    E = axes_across(n)  # two axes across the normal: the tilts' components
    sector = ((np.arctan2(pts @ E[1], pts @ E[0]) + np.pi) / (2 * np.pi) * SECTORS).astype(int) % SECTORS
    counts = np.bincount(sector, minlength=SECTORS)
    full = np.flatnonzero(counts >= MIN_SECTOR_POINTS)
    notes = []
    if len(full) >= 3:  # each sector's own normal: how far the ground's tilt varies around the vehicle
        t = np.array([E @ np.cross(n, _plane(pts[sector == k], up)[0]) for k in full])
        C = C + E.T @ (t.T @ t / len(t)) @ E
    else:
        notes.append(f"the ground seen in {len(full)} azimuth sectors only: its 1-sigma is the least-squares one")
    sig = float(np.sqrt(max(np.linalg.eigvalsh(C).max(), 0.0)))
    return LidarGround(normal=n, covariance_rad2=C, sigma_rad=sig, height_m=float(-d), inliers=int(inl.sum()),
                       rms_m=rms, sectors=len(full), notes=tuple(notes))


def _plane(pts: np.ndarray, up: np.ndarray) -> tuple[np.ndarray, float]:
    """Least-squares plane (unit normal towards ``up``, offset) through ``pts``."""
    c = pts.mean(axis=0)
    n = np.linalg.svd(pts - c, full_matrices=False)[2][2]
    if n @ up < 0:
        n = -n
    return n, float(c @ n)


def _ls_covariance(pts: np.ndarray, n: np.ndarray, rms: float) -> np.ndarray:
    """Covariance (3x3, LiDAR frame, rank 2) of the normal's small rotation from the points' spread."""
    q = pts - pts.mean(axis=0)
    # a rotation w tilts the normal by w x n: distances change by (w x n) . q = w . (n x q)
    A = np.cross(n, q)
    H = A.T @ A / max(rms, 1e-3) ** 2
    P = np.eye(3) - np.outer(n, n)
    return P @ np.linalg.pinv(P @ H @ P, rcond=1e-9) @ P
