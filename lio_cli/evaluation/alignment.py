"""Aligning an estimate to the reference: Umeyama SE(3)/Sim(3)/scale, origin, or none.

Definitions follow evo (and Umeyama, PAMI 1991): the alignment ``S`` maps the estimate's world frame into the
reference's, ``p_ref ~ s R p_est + t``; applied to poses it scales translations by ``s``, then left-multiplies
by ``[R | t]``. ``n_align`` restricts the fit to the first N associated poses.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..errors import InputError
from ..geometry import inv_pose

MODES = ("none", "se3", "sim3", "scale", "origin")


@dataclass
class Alignment:
    """``T_ref_est`` as rotation, translation and scale (identity for ``none``)."""

    mode: str
    rotation: np.ndarray  # (3,3)
    translation: np.ndarray  # (3,)
    scale: float
    n_used: int

    @property
    def matrix(self) -> np.ndarray:
        """The Sim(3) matrix [sR | t]."""
        S = np.eye(4)
        S[:3, :3] = self.scale * self.rotation
        S[:3, 3] = self.translation
        return S

    def apply(self, poses: np.ndarray) -> np.ndarray:
        """Aligned poses: translation s R p + t, rotation R R_p (scale only: translation s p)."""
        out = np.array(poses, dtype=np.float64, copy=True)
        out[:, :3, 3] *= self.scale
        if self.mode == "scale":
            return out
        out[:, :3, :3] = np.einsum("ij,njk->nik", self.rotation, out[:, :3, :3])
        out[:, :3, 3] = out[:, :3, 3] @ self.rotation.T + self.translation
        return out


def umeyama(src: np.ndarray, dst: np.ndarray, with_scale: bool) -> tuple[np.ndarray, np.ndarray, float]:
    """(R, t, s) minimising sum |dst_i - (s R src_i + t)|^2 over points (N,3); s = 1 unless ``with_scale``."""
    src = np.asarray(src, dtype=np.float64)
    dst = np.asarray(dst, dtype=np.float64)
    n = len(src)
    mu_src, mu_dst = src.mean(axis=0), dst.mean(axis=0)
    src_c, dst_c = src - mu_src, dst - mu_dst
    var_src = float(np.sum(src_c**2)) / n
    cov = dst_c.T @ src_c / n
    U, d, Vt = np.linalg.svd(cov)
    if np.count_nonzero(d > np.finfo(d.dtype).eps) < 2:
        raise InputError(
            "the trajectory is degenerate for Umeyama alignment (positions on a line or a point); "
            "use --align origin or --align none"
        )
    S = np.eye(3)
    if np.linalg.det(U) * np.linalg.det(Vt) < 0.0:
        S[2, 2] = -1.0  # a rotation, not a reflection
    R = U @ S @ Vt
    s = float(np.trace(np.diag(d) @ S) / var_src) if with_scale else 1.0
    t = mu_dst - s * (R @ mu_src)
    return R, t, s


def align(ref_poses: np.ndarray, est_poses: np.ndarray, mode: str = "se3", n_align: int | None = None) -> Alignment:
    """The alignment of ``est_poses`` onto ``ref_poses`` (paired, same length)."""
    if mode not in MODES:
        raise InputError(f"unknown alignment '{mode}' (choose from {', '.join(MODES)})")
    n = len(est_poses) if n_align is None or n_align <= 0 else min(int(n_align), len(est_poses))
    if mode == "none":
        return Alignment(mode, np.eye(3), np.zeros(3), 1.0, 0)
    if mode == "origin":
        T = ref_poses[0] @ inv_pose(est_poses[0])
        return Alignment(mode, T[:3, :3].copy(), T[:3, 3].copy(), 1.0, 1)
    R, t, s = umeyama(est_poses[:n, :3, 3], ref_poses[:n, :3, 3], with_scale=mode in ("sim3", "scale"))
    if mode == "scale":
        return Alignment(mode, np.eye(3), np.zeros(3), s, n)
    return Alignment(mode, R, t, s, n)
