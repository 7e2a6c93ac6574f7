"""A height prior beside odometry, on a wheeled platform whose IMU and wheels find the motion near a plane.

A scan matcher's height drifts with its pitch (metres over a few hundred), and the graph followed it: its tight
pose priors hold the attitude to the odometry's (tied to the world by the filter's start), and the wheels' only
height information is the non-holonomic zero vertical speed, which a body on its suspension breaks every 0.1 s.
Where the IMU's gravity direction and the wheels' distance (``choose.gravity_evidence``: the climb integrated
from the pitch less its median; the evidence and thresholds that choose the planar estimator) say the motion
stays within ``climb_m`` of a plane, every ``EVERY_KEYFRAMES``-th keyframe's height gets a prior: within that
climb (at least ``MIN_SIGMA_M``) of the first keyframe's. The odometry's poses then hold tilt and height less
(their sigmas times ``ODOM_TILT_SIGMA_SCALE`` and ``ODOM_VERTICAL_SIGMA_SCALE``), so the IMU's gravity and the
prior set them; the graph starts at the prior's height (``run``). A platform the evidence finds climbing (or
without wheels, or without odometry) gets none of this.
"""

from __future__ import annotations

from dataclasses import dataclass

import gtsam
import numpy as np
from gtsam.symbol_shorthand import X

from .. import choose
from ..timeline import Prepared

ENABLED = True
EVERY_KEYFRAMES = 3  # a prior every 0.3 s at the 0.1 s grid (every 1 s: the car's bad-wheel climb, 0.5 m, too loose)
MIN_SIGMA_M = 0.05  # never tighter than this (bumps, the evidence's own noise)
ODOM_TILT_SIGMA_SCALE = 10.0  # odometry poses' roll and pitch sigmas beside the prior
ODOM_VERTICAL_SIGMA_SCALE = 10.0  # and their vertical position's
MODEL = "height prior: the motion near a plane by IMU and wheels"


@dataclass(frozen=True)
class Level:
    """The height prior of one log: its sigma and the evidence it came from (for the metrics)."""
    sigma_m: float
    evidence: dict


def level(prep: Prepared) -> Level | None:
    """The prior when the wheels and IMU find the motion near a plane (module docstring), else None."""
    if not ENABLED:
        return None
    ev = choose.gravity_evidence(prep)
    if ev is None:
        return None
    limit = max(choose.MIN_CLIMB_M, choose.CLIMB_SHARE * ev["path_m"])
    if ev["tilt_p95_deg"] > choose.MAX_TILT_DEG or ev["climb_m"] > limit:
        return None
    return Level(max(float(ev["climb_m"]), MIN_SIGMA_M), ev)


def _height(z: float):
    """A CustomFactor's error function: the keyframe's height minus ``z``."""
    def error(this, values, H):
        T = values.atPose3(this.keys()[0])
        if H is not None:
            H[0] = np.hstack([np.zeros(3), T.rotation().matrix()[2]]).reshape(1, 6)
        return np.array([T.translation()[2] - z])
    return error


def add(g: gtsam.NonlinearFactorGraph, lv: Level, z_ref: float, k0: int, k1: int) -> int:
    """The priors on keyframes [k0, k1) that are multiples of ``EVERY_KEYFRAMES``; how many."""
    model = gtsam.noiseModel.Isotropic.Sigma(1, lv.sigma_m)
    ks = range(-(-k0 // EVERY_KEYFRAMES) * EVERY_KEYFRAMES, k1, EVERY_KEYFRAMES)
    for k in ks:
        g.add(gtsam.CustomFactor(model, [X(k)], _height(z_ref)))
    return len(ks)
