"""Small pose comparisons the odometry's plausibility checks and recovery share."""

from __future__ import annotations

import numpy as np

from ...geometry import inv_pose, so3_exp, so3_log


def untouched(measured: np.ndarray, guess: np.ndarray) -> bool:
    """The registration returned its guess (to 1e-12): it found no correspondence. ``np.allclose(measured,
    guess, rtol=0, atol=1e-12)`` written out, without np.isclose's overhead."""
    return bool(np.abs(measured - guess).max() <= 1e-12)


def exceeds_jump(measured: np.ndarray, guess: np.ndarray, max_m: float, max_rad: float) -> bool:
    """The registration moved further than ``max_m`` or turned more than ``max_rad`` from its guess."""
    jump = inv_pose(guess) @ measured
    angle = np.arccos(np.clip((np.trace(jump[:3, :3]) - 1.0) / 2.0, -1.0, 1.0))
    return bool(np.linalg.norm(jump[:3, 3]) > max_m or angle > max_rad)


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
