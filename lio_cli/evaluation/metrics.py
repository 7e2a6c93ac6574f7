"""Pose error metrics: APE, RPE, their statistics (as evo defines them), KITTI segment errors, drift.

Conventions: ``ref`` (Q) and ``est`` (P) are paired pose arrays (N,4,4) ``T_world_body``.
APE error pose ``E_i = P_i^-1 Q_i``; RPE error pose ``E_ij = (Q_i^-1 Q_j)^-1 (P_i^-1 P_j)``.
Relations: ``trans`` |translation| (APE: |p_est - p_ref|), ``rot`` rotation angle of E (rad; reported in deg),
``full`` Frobenius norm |E - I|.
"""

from __future__ import annotations

import math

import numpy as np

from ..errors import InputError
from ..geometry import inv_pose, so3_log_batch

STATISTICS = ("rmse", "mean", "median", "std", "min", "max", "sse")
DELTA_UNITS = ("frames", "m", "s", "deg", "rad")
KITTI_LENGTHS_M = (100.0, 200.0, 300.0, 400.0, 500.0, 600.0, 700.0, 800.0)
KITTI_STEP_FRAMES = 10  # the KITTI devkit starts a segment every 10th frame


def statistics(errors: np.ndarray) -> dict[str, float]:
    """rmse, mean, median, std (population), min, max, sse of an error array, as evo computes them."""
    e = np.asarray(errors, dtype=np.float64)
    sq = np.power(e, 2)
    return {
        "rmse": math.sqrt(np.mean(sq)),
        "mean": float(np.mean(e)),
        "median": float(np.median(e)),
        "std": float(np.std(e)),
        "min": float(np.min(e)),
        "max": float(np.max(e)),
        "sse": float(np.sum(sq)),
    }


def rotation_angle_rad(R: np.ndarray) -> np.ndarray:
    """Angle of rotation matrices (N,3,3), in [0, pi] (norm of the rotation vector)."""
    return np.linalg.norm(so3_log_batch(R), axis=1)


def _relation_errors(E: np.ndarray) -> dict[str, np.ndarray]:
    rot = rotation_angle_rad(E[:, :3, :3])
    return {
        "trans": np.linalg.norm(E[:, :3, 3], axis=1),
        "rot": np.rad2deg(rot),
        "rot_rad": rot,
        "full": np.linalg.norm((E - np.eye(4)).reshape(len(E), 16), axis=1),
    }


def ape_errors(ref: np.ndarray, est: np.ndarray) -> dict[str, np.ndarray]:
    """Per-pose APE arrays: trans (m), rot (deg), rot_rad, full."""
    E = inv_pose(est) @ ref
    out = _relation_errors(E)
    out["trans"] = np.linalg.norm(est[:, :3, 3] - ref[:, :3, 3], axis=1)
    return out


def rpe_errors(ref: np.ndarray, est: np.ndarray, pairs: np.ndarray) -> dict[str, np.ndarray]:
    """Per-pair RPE arrays (trans m, rot deg, rot_rad, full) for index pairs (M,2)."""
    i, j = pairs[:, 0], pairs[:, 1]
    Q = inv_pose(ref[i]) @ ref[j]
    P = inv_pose(est[i]) @ est[j]
    return _relation_errors(inv_pose(Q) @ P)


def _consecutive(steps: np.ndarray, delta: float) -> np.ndarray:
    """Pairs (start, end) of consecutive windows whose accumulated ``steps`` reach ``delta`` (evo's order)."""
    ids = [0]
    acc = 0.0
    for k, step in enumerate(steps.tolist(), start=1):
        acc += step
        if acc >= delta:
            ids.append(k)
            acc = 0.0
    ids_a = np.asarray(ids, dtype=np.int64)
    return np.stack([ids_a[:-1], ids_a[1:]], axis=1)


def _all_pairs_by_cumulative(cum: np.ndarray, delta: float, tol: float) -> np.ndarray:
    """For each i, the j > i whose ``cum[j] - cum[i]`` is closest to ``delta`` (first on ties), within ``tol``."""
    n = len(cum)
    i = np.arange(n - 1)
    k = np.searchsorted(cum, cum[i] + delta)
    best_j = np.full(n - 1, -1)
    best_e = np.full(n - 1, np.inf)
    for off in (-2, -1, 0, 1):
        j = np.clip(k + off, i + 1, n - 1)
        e = np.abs((cum[j] - cum[i]) - delta)
        better = e < best_e
        best_e = np.where(better, e, best_e)
        best_j = np.where(better, j, best_j)
    # equal cumulative values give equal errors: numpy's argmin takes the first of them
    first = np.maximum(np.searchsorted(cum, cum[best_j], side="left"), i + 1)
    ok = best_e <= tol
    return np.stack([i[ok], first[ok]], axis=1).astype(np.int64)


def rpe_pairs(
    poses: np.ndarray,
    stamps_ns: np.ndarray,
    delta: float,
    unit: str = "frames",
    all_pairs: bool = False,
    rel_tol: float = 0.1,
) -> np.ndarray:
    """Index pairs (M,2) for RPE over ``delta`` in frames, m (path), s, deg or rad (accumulated angle).

    Consecutive pairs: windows start at 0 and close once the accumulated motion reaches delta; all pairs: every
    start i with the end closest to delta (within ``rel_tol * delta``; frames: exactly i + delta). Frames, metres
    and angles match evo's ``id_pairs_from_delta``; seconds (not in evo) measure elapsed time the same way.
    """
    n = len(poses)
    if unit not in DELTA_UNITS:
        raise InputError(f"unknown delta unit '{unit}' (choose from {', '.join(DELTA_UNITS)})")
    if not delta > 0:
        raise InputError(f"--delta must be positive, got {delta}")
    if unit == "frames":
        if float(delta) != int(delta):
            raise InputError(f"--delta must be a whole number of frames, got {delta}")
        d = int(delta)
        if all_pairs:
            i = np.arange(max(n - d, 0))
        else:
            ids = np.arange(0, n, d)
            i = ids[:-1]
        pairs = np.stack([i, i + d], axis=1)
    else:
        tol = delta * rel_tol
        if unit == "m":
            steps = np.linalg.norm(np.diff(poses[:, :3, 3], axis=0), axis=1)
            target = delta
        elif unit == "s":
            steps = np.diff(np.asarray(stamps_ns, dtype=np.int64)) / 1e9
            target = delta
        else:
            limit = 180.0 if unit == "deg" else np.pi
            if delta > limit:
                raise InputError(f"--delta {delta} {unit} is beyond a half turn ({limit:g} {unit})")
            target = np.deg2rad(delta) if unit == "deg" else delta
            tol = np.deg2rad(tol) if unit == "deg" else tol
            R = poses[:, :3, :3]
            steps = rotation_angle_rad(np.einsum("nji,njk->nik", R[:-1], R[1:])) if n > 1 else np.zeros(0)
        if not all_pairs:
            pairs = _consecutive(steps, target)
        elif unit in ("m", "s"):
            cum = np.concatenate([[0.0], np.cumsum(steps)]) if unit == "m" else (
                (np.asarray(stamps_ns, dtype=np.int64) - stamps_ns[0]) / 1e9)
            pairs = _all_pairs_by_cumulative(cum, target, tol) if n > 1 else np.zeros((0, 2), np.int64)
        else:
            pairs = _all_pairs_by_angle(poses[:, :3, :3], target, tol)
    if len(pairs) == 0:
        raise InputError(
            f"RPE with --delta {delta:g} {unit} found no pose pairs among {n} poses; lower --delta"
            + (" or raise --delta-tol" if all_pairs and unit != "frames" else "")
        )
    return pairs.astype(np.int64)


def _all_pairs_by_angle(R: np.ndarray, delta_rad: float, tol_rad: float) -> np.ndarray:
    """Every pair i < j whose direct relative rotation angle is within delta +- tol (quadratic, as in evo)."""
    out = []
    for i in range(len(R) - 1):
        ang = np.linalg.norm(so3_log_batch(R[i].T @ R[i + 1:]), axis=1)
        j = np.flatnonzero((delta_rad - tol_rad <= ang) & (ang <= delta_rad + tol_rad)) + i + 1
        out.append(np.stack([np.full(len(j), i), j], axis=1))
    return np.concatenate(out) if out else np.zeros((0, 2), np.int64)


def path_length_m(poses: np.ndarray) -> float:
    return float(np.sum(np.linalg.norm(np.diff(poses[:, :3, 3], axis=0), axis=1)))


def kitti_segment_errors(
    ref: np.ndarray, est: np.ndarray, lengths_m: tuple[float, ...] = KITTI_LENGTHS_M, step: int = KITTI_STEP_FRAMES
) -> dict:
    """KITTI odometry benchmark errors (devkit ``evaluate_odometry``) over segments of the reference path.

    A segment starts at every ``step``-th frame ``i`` and ends at the first frame ``j`` whose reference path
    distance exceeds ``dist[i] + L``. Per segment: ``E = (P_i^-1 P_j)^-1 (Q_i^-1 Q_j)``, translation error
    |t(E)| / L and rotation error angle(E) / L. Reported: means over all segments, translation in % and
    rotation in deg per 100 m, overall and per length.
    """
    dist = np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(ref[:, :3, 3], axis=0), axis=1))])
    firsts = np.arange(0, len(ref), step)
    t_errs, r_errs, lens = [], [], []
    per_length = {}
    for L in lengths_m:
        last = np.searchsorted(dist, dist[firsts] + L, side="right")
        ok = last < len(ref)
        i, j = firsts[ok], last[ok]
        if len(i) == 0:
            continue
        Q = inv_pose(ref[i]) @ ref[j]
        P = inv_pose(est[i]) @ est[j]
        E = inv_pose(P) @ Q
        # devkit: angle = acos(clamp((trace - 1) / 2))
        cos = np.clip((np.trace(E[:, :3, :3], axis1=1, axis2=2) - 1.0) * 0.5, -1.0, 1.0)
        r = np.arccos(cos) / L
        t = np.linalg.norm(E[:, :3, 3], axis=1) / L
        t_errs.append(t)
        r_errs.append(r)
        lens.append(np.full(len(t), L))
        per_length[f"{L:g}"] = {"segments": int(len(t)), "trans_pct": float(np.mean(t) * 100.0),
                                "rot_deg_per_100m": float(np.rad2deg(np.mean(r)) * 100.0)}
    if not t_errs:
        return {"segments": 0, "trans_pct": None, "rot_deg_per_100m": None, "per_length": {},
                "note": f"reference path ({dist[-1]:.1f} m) is shorter than the shortest segment ({min(lengths_m):g} m)"}
    t_all, r_all = np.concatenate(t_errs), np.concatenate(r_errs)
    return {"segments": int(len(t_all)), "trans_pct": float(np.mean(t_all) * 100.0),
            "rot_deg_per_100m": float(np.rad2deg(np.mean(r_all)) * 100.0), "per_length": per_length}


def drift(ref: np.ndarray, est: np.ndarray) -> dict[str, float | None]:
    """Final-position error (m) and that error per distance travelled along the reference (%)."""
    final = float(np.linalg.norm(est[-1, :3, 3] - ref[-1, :3, 3]))
    length = path_length_m(ref)
    return {"final_error_m": final, "path_length_m": length,
            "drift_pct": final / length * 100.0 if length > 0 else None}
