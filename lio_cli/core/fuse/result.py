"""The outcome of a fusion run: the trajectory at the output stamps, per-pose covariance, and counters.

The trajectory starts at the origin of its world frame (z up): positions are shifted so the first output
pose sits at (0, 0, 0); orientations keep the world's heading (zero at the start, or the IMU's own
orientation's, or ENU with GPS).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from .report import SourceReport

# 6x6 pose covariance layout: position error in world axes (m^2), then rotation error as a right
# perturbation in base axes (rad^2): T_true = T_est with R_true = R_est exp(dtheta), p_true = p_est + dp.
COVARIANCE_LAYOUT = ("x_m", "y_m", "z_m", "rot_x_rad", "rot_y_rad", "rot_z_rad")


@dataclass
class FuseResult:
    stamps_ns: np.ndarray  # (N,) int64
    poses: np.ndarray  # (N,4,4) T_world_base
    covariances: np.ndarray | None  # (N,6,6), COVARIANCE_LAYOUT
    velocities_mps: np.ndarray | None  # (N,3) world
    estimator: str
    smoothed: bool
    reports: dict[str, SourceReport]
    info: dict = field(default_factory=dict)
    # where the first pose lies horizontally in the fixes' ENU frame (``GpsSeries.position_enu_m``), before
    # ``anchor_to_origin`` moved it to the origin; None where no fix placed the world
    origin_enu_xy_m: np.ndarray | None = None

    def __len__(self) -> int:
        return len(self.stamps_ns)

    def summary(self) -> dict:
        """JSON-able: estimator, sources with their counters, and the run's notes (for metrics.json)."""
        return {"estimator": self.estimator, "smoothed": self.smoothed, "poses": len(self),
                "sources": {k: v.to_dict() for k, v in self.reports.items()}, **self.info}


def anchor_to_origin(poses: np.ndarray) -> np.ndarray:
    """Shift positions so the first pose is at the origin (orientation and heading unchanged)."""
    out = poses.copy()
    if len(out):
        out[:, :3, 3] -= poses[0, :3, 3]
    return out


def enu_origin(poses: np.ndarray, world_enu_xy_m: np.ndarray | None) -> np.ndarray | None:
    """``FuseResult.origin_enu_xy_m`` of ``poses`` in an estimator's world (before ``anchor_to_origin``) whose origin
    lies at ``world_enu_xy_m`` in the fixes' ENU frame (None: no fix placed it)."""
    if world_enu_xy_m is None or not len(poses):
        return None
    return poses[0, :2, 3] + np.asarray(world_enu_xy_m, float)[:2]


def pose_covariance_index(rot_idx: slice, pos_idx: slice) -> np.ndarray:
    """Error-state indices that put a covariance in COVARIANCE_LAYOUT order (position, then rotation)."""
    return np.r_[np.arange(pos_idx.start, pos_idx.stop), np.arange(rot_idx.start, rot_idx.stop)]
