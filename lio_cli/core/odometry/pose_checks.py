"""Small pose comparisons the odometry's plausibility checks and recovery share."""

from __future__ import annotations

import math

import numpy as np

from ...geometry import so3_exp, so3_log


def untouched(measured: np.ndarray, guess: np.ndarray) -> bool:
    """The registration returned its guess (to 1e-12): it found no correspondence. ``np.allclose(measured,
    guess, rtol=0, atol=1e-12)`` written out, without np.isclose's overhead."""
    return bool(np.abs(measured - guess).max() <= 1e-12)


def exceeds_jump(measured: np.ndarray, guess: np.ndarray, max_m: float, max_rad: float) -> bool:
    """The registration moved further than ``max_m`` or turned more than ``max_rad`` from its guess: the
    translation and angle of ``inv_pose(guess) @ measured``, in Python floats (a dozen numpy calls on 4x4
    matrices cost more than the arithmetic; they agree to rounding)."""
    (g0, g1, g2, gt), (g3, g4, g5, gu), (g6, g7, g8, gv) = guess.tolist()[:3]
    (m0, m1, m2, mt), (m3, m4, m5, mu), (m6, m7, m8, mv) = measured.tolist()[:3]
    dx, dy, dz = mt - gt, mu - gu, mv - gv
    jx, jy, jz = g0 * dx + g3 * dy + g6 * dz, g1 * dx + g4 * dy + g7 * dz, g2 * dx + g5 * dy + g8 * dz
    trace = (g0 * m0 + g3 * m3 + g6 * m6) + (g1 * m1 + g4 * m4 + g7 * m7) + (g2 * m2 + g5 * m5 + g8 * m8)
    angle = math.acos(min(max((trace - 1.0) / 2.0, -1.0), 1.0))
    return math.sqrt(jx * jx + jy * jy + jz * jz) > max_m or angle > max_rad


def lean_on_prior(measured: np.ndarray, guess: np.ndarray, dirs_b: list[np.ndarray]) -> np.ndarray:
    """The measured pose, except along directions the scan cannot see, where the prior is kept."""
    pose = measured.copy()
    if dirs_b:
        R = guess[:3, :3]
        dp = measured[:3, 3] - guess[:3, 3]
        for d in dirs_b:
            dw = R @ d
            dp = dp - dw * (dw @ dp)
        pose[:3, 3] = guess[:3, 3] + dp
    return pose


def scale_delta(delta: np.ndarray, factor: float) -> np.ndarray:
    """The relative motion ``delta`` stretched to ``factor`` of its duration (constant velocity)."""
    if abs(factor - 1.0) < 1e-9:
        return delta
    out = np.eye(4)
    out[:3, :3] = so3_exp(so3_log(delta[:3, :3]) * factor)
    out[:3, 3] = delta[:3, 3] * factor
    return out
