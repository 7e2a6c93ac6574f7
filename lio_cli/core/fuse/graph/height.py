"""A height prior beside odometry, on a wheeled platform whose IMU and wheels find the motion near a plane.

A scan matcher's height drifts with its pitch (metres over a few hundred), and the graph followed it: its pose
priors hold height and attitude to the odometry's, and the wheels' only height information is the
non-holonomic zero vertical speed, which a body on its suspension breaks every 0.1 s. Where the IMU's gravity
direction and the wheels' distance (``choose.gravity_evidence``: the climb integrated from the pitch less its
level fitted along the distance, slip windows and ``SLIP_DILATE`` either side left out; the planar estimator's
thresholds; the wheel speed times the scale found against the odometry and the windows it finds slipping left
out too, ``wheels.against_odometry``: else a scale error reads as pitch wherever the speed changes) say the motion
stays within ``climb_m`` of a plane, every ``EVERY_KEYFRAMES``-th keyframe's height gets a prior: within that
climb (``MIN_SIGMA_M`` .. ``MAX_SIGMA_M``) of the first keyframe's. The odometry poses' vertical, roll and pitch
sigmas are then multiplied by ``ODOM_VERTICAL_SIGMA_SCALE`` and ``ODOM_TILT_SIGMA_SCALE`` so their drift no longer
outweighs it (the IMU's gravity sets the tilt), and the graph starts at the prior's height (``run``). A platform
the evidence finds tilting or climbing, or too vaguely level, or whose odometry already stays within the prior's
height, gets none of this.
"""

from __future__ import annotations

from dataclasses import dataclass

import gtsam
import numpy as np
from gtsam.symbol_shorthand import X

from .. import choose
from . import wheels
from ..timeline import Prepared

ENABLED = True
EVERY_KEYFRAMES = 10  # a prior every 1 s at the 0.1 s grid
SLIP_DILATE = 1  # the evidence's slip windows widened by one on each side (a slip's onset and end)
MIN_SIGMA_M = 0.1  # never tighter: the evidence's own noise (0.22 m on a 320 m drive flat to 0.03 m)
# a climb beyond this: IMU and wheels too vague to hold the height better than the odometry, no prior
MAX_SIGMA_M = 0.3
ODOM_VERTICAL_SIGMA_SCALE = 10.0  # odometry poses' vertical sigma beside the prior
ODOM_TILT_SIGMA_SCALE = 10.0  # and their roll and pitch sigmas (the IMU's gravity then sets the tilt)
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
    found = None
    if prep.odom is not None and len(prep.odom) > 1 and prep.wheel is not None and len(prep.wheel) > 1:
        found = wheels.against_odometry(prep.wheel, prep.odom)
    scale, slips = (1.0, None) if found is None else (found.scale, found.slips_ns)
    ev = choose.gravity_evidence(prep, SLIP_DILATE, scale, slips, level_fit=True)
    if ev is None:
        return None
    if found is not None:
        ev = {**ev, "wheel_scale": round(found.scale, 4), "odom_slip_windows": len(found.slips_ns)}
    if ev["tilt_p95_deg"] > choose.MAX_TILT_DEG or ev["climb_m"] > MAX_SIGMA_M:  # MAX_SIGMA_M < choose's climb limit
        return None
    sigma = max(float(ev["climb_m"]), MIN_SIGMA_M)
    if found is not None:
        ev["odom_vertical_m"] = round(float(np.ptp(prep.odom.poses[:, 2, 3])), 3)
        if ev["odom_vertical_m"] <= sigma:  # the odometry's height already within the prior's: nothing to hold
            return None
    return Level(sigma, ev)


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
