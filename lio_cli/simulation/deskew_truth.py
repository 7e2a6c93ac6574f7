"""The exact motion of a simulated run, to judge de-skewed clouds against.

``TrueMotion.deskewed`` moves each measured point with the scenario's analytic trajectory (not its sampled
``x.gt.tum``) into the sensor frame at the reference instant: what a perfect de-skew gives. Points a
standing sensor would see there, to within the range noise, since each was measured from the exact pose at
its stamp.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from ..geometry import inv_pose
from .scenarios import build_scenario


class TrueMotion:
    def __init__(self, truth_path: str | Path) -> None:
        truth = json.loads(Path(truth_path).read_text())
        conditions = truth.get("conditions", {})
        self.scenario = build_scenario(truth["scenario"], start=conditions.get("start", "still"),
                                       tilt_scale=conditions.get("tilt_scale", 1.0),
                                       stops=tuple((s["start_s"], s["duration_s"]) for s in truth.get("stops", ())),
                                       hills=_hills(truth.get("hills")))
        self.T_base_lidar = np.asarray(truth["T_base_lidar"], dtype=np.float64)
        self.start_ns = int(truth["start_ns"])

    def poses(self, stamps_ns: np.ndarray) -> np.ndarray:
        """T_world_base (N,4,4) at ``stamps_ns``."""
        return self.scenario.trajectory.poses((np.asarray(stamps_ns, dtype=np.int64) - self.start_ns) * 1e-9)

    def deskewed(self, points_lidar: np.ndarray, stamps_ns: np.ndarray, t_ref_ns: int) -> np.ndarray:
        """Points (N,3) measured at ``stamps_ns``, in the sensor frame at ``t_ref_ns``, moved with the true motion."""
        T_ref = self.poses(np.array([t_ref_ns]))[0] @ self.T_base_lidar
        rel = inv_pose(T_ref)[None] @ self.poses(stamps_ns) @ self.T_base_lidar
        return np.einsum("nij,nj->ni", rel[:, :3, :3], points_lidar) + rel[:, :3, 3]


def _hills(entry: dict | None) -> tuple[float, float] | None:
    return None if entry is None else (entry["amplitude_m"], entry["wavelength_m"])
