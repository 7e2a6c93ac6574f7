"""Aligning an estimate to the reference: Umeyama SE(3)/Sim(3)/scale, 4-DoF position + yaw, origin, or none.

Definitions follow evo (and Umeyama, PAMI 1991): the alignment ``S`` maps the estimate's world frame into the
reference's, ``p_ref ~ s R p_est + t``; applied to poses it scales translations by ``s``, then left-multiplies
by ``[R | t]``. ``n_align`` restricts the fit to the first N associated poses. ``posyaw`` fits a translation
and a rotation about world z only (4 DoF, as rpg_trajectory_evaluation does for visual/LiDAR-inertial
estimates, whose roll and pitch are observable through gravity).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..errors import InputError
from ..geometry import inv_pose

MODES = ("none", "se3", "sim3", "scale", "origin", "posyaw")


class DegenerateAlignment(InputError):
    """Positions on a line or a point: no rotation (Umeyama) to align them by."""


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
        raise DegenerateAlignment(
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


def posyaw(src: np.ndarray, dst: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(R about z, t) minimising sum |dst_i - (R src_i + t)|^2 over points (N,3), R a rotation about world z.

    Closed form: with centred points a = src - mean, b = dst - mean, the cost is minimal at
    yaw = atan2(sum(a_x b_y - a_y b_x), sum(a_x b_x + a_y b_y)), and t = mean(dst) - R mean(src).
    """
    src = np.asarray(src, dtype=np.float64)
    dst = np.asarray(dst, dtype=np.float64)
    mu_src, mu_dst = src.mean(axis=0), dst.mean(axis=0)
    a, b = src - mu_src, dst - mu_dst
    sin_sum = float(np.sum(a[:, 0] * b[:, 1] - a[:, 1] * b[:, 0]))
    cos_sum = float(np.sum(a[:, 0] * b[:, 0] + a[:, 1] * b[:, 1]))
    spread = float(np.sqrt(np.sum(a[:, :2] ** 2) * np.sum(b[:, :2] ** 2)))
    if not spread > 0.0 or np.hypot(sin_sum, cos_sum) <= 1e-12 * spread:
        raise InputError(
            "the trajectory is degenerate for posyaw alignment (no horizontal extent to fix the yaw); "
            "use --align none"
        )
    yaw = np.arctan2(sin_sum, cos_sum)
    c, s = np.cos(yaw), np.sin(yaw)
    R = np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])
    return R, mu_dst - R @ mu_src


def line_spread(positions: np.ndarray) -> tuple[float, float]:
    """(std across, std along) the main direction of ``positions`` (N,3): how little an se3/sim3 alignment of
    them has to fix its rotation about that line by."""
    sv = np.linalg.svd(positions - positions.mean(axis=0), compute_uv=False) / np.sqrt(len(positions))
    return float(sv[1]), float(sv[0])


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
    if mode == "posyaw":
        R, t = posyaw(est_poses[:n, :3, 3], ref_poses[:n, :3, 3])
        return Alignment(mode, R, t, 1.0, n)
    R, t, s = umeyama(est_poses[:n, :3, 3], ref_poses[:n, :3, 3], with_scale=mode in ("sim3", "scale"))
    if mode == "scale":
        return Alignment(mode, np.eye(3), np.zeros(3), s, n)
    return Alignment(mode, R, t, s, n)
