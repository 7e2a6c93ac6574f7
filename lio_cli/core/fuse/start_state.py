"""The filters' first state (``initial.initial_state`` finds it; ``pieces`` hands it from one piece of a log to
the next), in a module of its own so ``inputs.FuseOptions`` can carry one without importing the timeline."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np


@dataclass
class Start:
    R: np.ndarray  # R_world_base
    v: np.ndarray  # world velocity
    bg: np.ndarray  # gyro bias, base frame
    v_sigma_mps: float
    bg_sigma_radps: float
    standing: bool
    yaw_from: str  # "imu_orientation", "start" (yaw zero at the start) or "handover" (``pieces``)
    reason: str
    yaw_sigma_rad: float = 0.0  # a handed-over heading's (``pieces``)
    ba: np.ndarray | None = None  # a handed-over accelerometer bias, base frame (``pieces``)


__all__ = ["Start"]
