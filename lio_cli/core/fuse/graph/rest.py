"""The graph at rest (``core.fuse.rest``): zero motion between consecutive keyframes inside one span at rest, and
zero velocity at each, so the IMU factors there explain the gyro's and accelerometer's readings as their biases."""

from __future__ import annotations

import gtsam
import numpy as np
from gtsam.symbol_shorthand import V, X

from ..rest import REST_POSITION_SIGMA_M, REST_ROTATION_SIGMA_RAD, REST_VELOCITY_SIGMA_MPS, at_rest


def add(g: gtsam.NonlinearFactorGraph, kt: np.ndarray, spans: np.ndarray | None, k0: int, k1: int) -> int:
    """The rest factors of keyframes [k0, k1) (their count)."""
    if spans is None or not len(spans):
        return 0
    inside = at_rest(spans, kt[k0:k1])  # two spans lie a window apart: consecutive keyframes share one
    vel = gtsam.noiseModel.Isotropic.Sigma(3, REST_VELOCITY_SIGMA_MPS)
    n = 0
    for a in np.flatnonzero(inside[:-1] & inside[1:]).tolist():
        k = k0 + a
        sig = np.r_[np.full(3, REST_ROTATION_SIGMA_RAD), np.full(3, REST_POSITION_SIGMA_M)]
        g.add(gtsam.BetweenFactorPose3(X(k), X(k + 1), gtsam.Pose3(), gtsam.noiseModel.Diagonal.Sigmas(sig)))
        g.add(gtsam.PriorFactorVector(V(k), np.zeros(3), vel))
        n += 1
    return n
