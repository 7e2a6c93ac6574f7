"""Which directions of a 3-vector estimate the motion left unobservable, in words a user can act on.

An extrinsic is seen only through the motion: rotating about one axis only hides the mounting's rotation about
that axis and the lever arm along it (a ground vehicle turning about the vertical cannot show the vertical
lever arm; from its rotations alone, not the mounting's yaw either).
"""

from __future__ import annotations

import numpy as np

AXES = ("x", "y", "z")


def axis_name(v: np.ndarray, frame: str = "LiDAR") -> str:
    """'the LiDAR z axis' for a direction within ~25 deg of a frame axis, else the direction itself."""
    v = np.asarray(v, np.float64) / np.linalg.norm(v)
    k = int(np.argmax(np.abs(v)))
    if abs(v[k]) > 0.9:
        return f"the {frame} {AXES[k]} axis"
    return f"the {frame} direction ({v[0]:+.2f}, {v[1]:+.2f}, {v[2]:+.2f})"


def weak_directions(cov: np.ndarray, max_sigma: float) -> list[tuple[np.ndarray, float]]:
    """Unit directions (eigenvectors of ``cov``) whose 1-sigma exceeds ``max_sigma``, weakest first."""
    w, V = np.linalg.eigh(0.5 * (cov + cov.T))
    out = [(V[:, i], float(np.sqrt(max(w[i], 0.0)))) for i in np.argsort(w)[::-1] if np.sqrt(max(w[i], 0.0)) > max_sigma]
    return out


def floored(cov: np.ndarray, floor: np.ndarray | None) -> np.ndarray:
    """``cov`` with each axis' variance raised to ``floor**2`` where it is below (a diagonal added: still a
    covariance; NaN floors count as none)."""
    if floor is None:
        return cov
    f = np.nan_to_num(np.asarray(floor, np.float64), nan=0.0)
    return cov + np.diag(np.maximum(f * f - np.diag(cov), 0.0))


def per_axis(cov: np.ndarray, max_sigma: float) -> tuple[np.ndarray, np.ndarray]:
    """(1-sigma along each frame axis, observable mask: sigma below ``max_sigma``)."""
    s = np.sqrt(np.maximum(np.diag(cov), 0.0))
    return s, s <= max_sigma


def turned_mostly_about(v: np.ndarray, axis: np.ndarray, share: float) -> bool:
    """Whether a platform whose rotation was ``share`` about ``axis`` (``dominant_rotation_axis``) turned
    mostly about the direction ``v``: what hides the mounting's rotation about it and the lever arm along it."""
    return abs(float(np.asarray(v, np.float64) @ axis)) > 0.9 and share > 0.9


def dominant_rotation_axis(phi: np.ndarray) -> tuple[np.ndarray, float]:
    """(unit axis, share of the rotation about it) of rotation increments (n,3): 1.0 means one axis only."""
    M = phi.T @ phi
    w, V = np.linalg.eigh(M)
    return V[:, -1], float(w[-1] / max(w.sum(), 1e-300))
