"""When the accelerometer checks the wheels (``wheel_slip``) before a filter, and whether it can measure their scale
at all (which the estimator choice asks: ``choose.CLIMB_SHARE``)."""

from __future__ import annotations

import copy
from dataclasses import replace

from . import wheel_slip
from .inputs import FuseOptions
from .timeline import Prepared


def scale_measured(prep: Prepared, o: FuseOptions) -> bool:
    """Whether the accelerometer measures the wheels' scale (a trial check on a copy, nothing counted, without the
    angle walk's share of the scale's sigma, which ``measured`` does not ask and whose matrix grows with the log's
    length squared): where it cannot, its axes may not be the base's and the climb it reads is no evidence
    (``choose``). Beside odometry, or without an accelerometer and wheel speed, False."""
    if "odom" in prep.use or not wheel_slip.applies(prep):
        return False
    trial = replace(prep, reports=copy.deepcopy(prep.reports))
    return wheel_slip.check_wheels(trial, o.gate_probability, o.gravity_mps2, walk=False).measured


def check(prep: Prepared, o: FuseOptions, estimator: str) -> None:
    """The accelerometer checks the wheels (slips bridged, scale applied; ``info["wheel_check"]``) for the planar
    filter, and for the 3D one without odometry (beside odometry the graph measures the wheels' scale and slips
    against it instead)."""
    if (estimator == "planar" or (estimator == "ekf" and "odom" not in prep.use)) and wheel_slip.applies(prep):
        prep.wheel_check = wheel_slip.check_wheels(prep, o.gate_probability, o.gravity_mps2).to_dict()
