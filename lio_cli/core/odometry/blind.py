"""A scan without a rotation prior (over an IMU gap): registered from yaw hypotheses around constant velocity,
each de-skewed by its own motion; the one whose points lie closest to the map wins."""

from __future__ import annotations

import numpy as np

from ...geometry import so3_exp
from ...model.records import PointCloud
from ..kdtree import ckdtree_class
from .priors import cv_knots
from .scan import prepare
from .state import OdomState
from .tuning import BLIND_GATE_M, BLIND_YAWS_RAD


def register_blind(o: OdomState, cloud: PointCloud, t_prev: int, t_ref: int, guess: np.ndarray):
    """(points, map frame, pose) of a scan without a rotation prior, or None if too few points: from yaw hypotheses
    about the world's up axis around ``guess``, each de-skewed by the motion it implies and again by the motion
    registered from it; the one whose points lie closest to the map (distances truncated at a voxel) is kept."""
    reg, g_world = o.reg, o.nav.g_world
    up = np.array([0.0, 0.0, 1.0]) if g_world is None else -g_world / np.linalg.norm(g_world)
    if o.gaps.blind_tree is None or o.gaps.blind_tree[:2] != (reg, reg.scans):  # the map grew or restarted
        o.gaps.blind_tree = (reg, reg.scans, ckdtree_class()(reg.map.point_cloud()))  # (map, its scans, tree)
    tree = o.gaps.blind_tree[2]  # the scans of one IMU gap stay out of the map: one tree serves them all
    best, best_cost = None, np.inf
    for yaw in BLIND_YAWS_RAD:
        pose = guess.copy()
        pose[:3, :3] = so3_exp(up * yaw) @ guess[:3, :3]
        for _ in range(2):  # de-skewed by the hypothesis' motion, then by the registered one
            points = prepare(o, cloud, *cv_knots(o.settings.deskew, o.track, pose, t_prev, t_ref), t_ref)
            if points is None:
                return None
            frame, source = reg.downsample(points)
            pose = reg.register(source, pose, adaptive=True, gate_m=BLIND_GATE_M)
            if not np.isfinite(pose).all():
                break
        else:
            d, _ = tree.query(source @ pose[:3, :3].T + pose[:3, 3], distance_upper_bound=reg.voxel_size_m)
            cost = float(np.mean(np.minimum(d, reg.voxel_size_m) ** 2))
            if cost < best_cost:
                best, best_cost = (points, frame, pose), cost
    return best if best is not None else (points, frame, pose)
