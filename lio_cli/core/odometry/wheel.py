"""Wheel odometry kinematics (lecture): forward speed and yaw rate integrated on the plane."""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from ...model.records import OdometryRecord


def mean_twist(records: Sequence[OdometryRecord], t0_ns: int, t1_ns: int) -> tuple[float, float] | None:
    """(mean forward speed m/s, mean yaw rate rad/s) of the records stamped in [t0, t1], None if there are none."""
    recs = [w for w in records if t0_ns <= w.stamp_ns <= t1_ns]
    if not recs:
        return None
    return float(np.mean([w.linear_mps[0] for w in recs])), float(np.mean([w.angular_radps[2] for w in recs]))


def planar_delta(v_mps: float, omega_radps: float, dt_s: float) -> np.ndarray:
    """T_base(t0)_base(t1) of a constant forward speed and yaw rate over ``dt_s`` (midpoint heading)."""
    th = omega_radps * dt_s
    T = np.eye(4)
    T[:2, :2] = [[np.cos(th), -np.sin(th)], [np.sin(th), np.cos(th)]]
    T[0, 3], T[1, 3] = v_mps * dt_s * np.cos(th / 2), v_mps * dt_s * np.sin(th / 2)
    return T


def wheel_speed(records: Sequence[OdometryRecord], t_ns: int, half_window_ns: int) -> float:
    """Mean forward speed of the records within ``half_window_ns`` of ``t_ns``, NaN if there are none."""
    twist = mean_twist(records, t_ns - half_window_ns, t_ns + half_window_ns)
    return np.nan if twist is None else twist[0]


def wheel_delta(records: Sequence[OdometryRecord], t0_ns: int, t1_ns: int, lead_ns: int,
                fallback: np.ndarray) -> np.ndarray:
    """Planar motion over [t0, t1] from the mean twist of the records in [t0 - lead, t1]; ``fallback`` if none."""
    twist = mean_twist(records, t0_ns - lead_ns, t1_ns)
    if twist is None:
        return fallback
    return planar_delta(twist[0], twist[1], (t1_ns - t0_ns) * 1e-9)
