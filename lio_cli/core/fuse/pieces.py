"""A log fused in pieces (``lio fuse --max-memory``): what a piece hands the next one.

``handover``: a piece's estimated state where the next piece starts (attitude, velocity, gyro bias and their
sigmas), that piece's ``Start`` in place of one found again from its own first second (a moving start knows no
gyro bias, and nothing but a standing start measures the planar filter's).
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from ...geometry import so3_exp_one
from .initial import Start
from .planar_model import BW, TH, V
from .state3d import B_, BA_, DB, R_, V_


def planar_handover(t_ns: np.ndarray, x: np.ndarray, P: np.ndarray, at_ns: int) -> Start:
    """The planar filter's state (``x``, ``P`` at knots ``t_ns``) at the first knot from ``at_ns`` on, as a
    ``Start`` in this piece's world."""
    k = min(int(np.searchsorted(t_ns, at_ns)), len(t_ns) - 1)
    R = so3_exp_one(np.array([0.0, 0.0, float(x[k, TH])]))
    return Start(R, R @ np.array([x[k, V], 0.0, 0.0]), np.array([0.0, 0.0, x[k, BW]]),
                 float(np.sqrt(P[k, V, V])), float(np.sqrt(P[k, BW, BW])), False, "handover",
                 f"handed over by the chunk before: speed {x[k, V]:.2f} m/s, gyro z bias {x[k, BW]:.5f} rad/s",
                 float(np.sqrt(P[k, TH, TH])))


def state_handover(t_ns: np.ndarray, states: dict[str, np.ndarray], at_ns: int, v_sigma_mps: float,
                   bg_sigma_radps: float) -> Start:
    """The 3D state (``R``, ``v``, ``bg``, ``ba`` per stamp of ``t_ns``: the graph's keyframes or the 3D filter's
    knots) at the first stamp from ``at_ns`` on, as a ``Start`` in this piece's world (loose velocity and gyro
    bias sigmas: the next piece's IMU, wheels and GPS find them again)."""
    k = min(int(np.searchsorted(t_ns, at_ns)), len(t_ns) - 1)
    v, bg = states["v"][k].copy(), states["bg"][k].copy()
    return Start(states["R"][k].copy(), v, bg, v_sigma_mps, bg_sigma_radps, False, "handover",
                 f"handed over by the chunk before: speed {np.linalg.norm(v):.2f} m/s, gyro bias "
                 f"{np.linalg.norm(bg):.5f} rad/s", ba=states["ba"][k].copy())


def filtered_handover(handed: tuple, v_sigma_mps: float, bg_sigma_radps: float) -> Start:
    """The 3D filter's state where the next piece starts (``Ekf3d.handed``)."""
    t_ns, x, _ = handed
    states = {"R": x[R_].reshape(1, 3, 3), "v": x[None, V_], "bg": x[None, B_], "ba": x[None, BA_]}
    return state_handover(np.array([t_ns]), states, t_ns, v_sigma_mps, bg_sigma_radps)


def bias_sigma(handed: tuple | None, gps: bool, start_sigma: float) -> float:
    """The handed gyro bias's sigma: without GPS the 3D filter's own (``Ekf3d.handed``: nothing in a moving piece
    observes the bias again, and at the start-up sigma the piece re-fitted it wrongly); with GPS the start-up one
    (the fixes find it again, and a tight wrong bias would be held). Measured in docs/benchmarks.md."""
    if gps or handed is None:
        return start_sigma
    return float(np.sqrt(np.max(np.diag(handed[2][DB, DB]))))


def turned_handover(start: Start | None, R: np.ndarray) -> Start | None:
    """A handed-over state carried by the world rotation ``R`` (a track placed on the GPS fixes)."""
    return None if start is None else replace(start, R=R @ start.R, v=R @ start.v)


__all__ = ["bias_sigma", "filtered_handover", "planar_handover", "state_handover", "turned_handover"]
