"""Gravity at a moving start: the IMU aligned with the odometry poses, or the wheels, over the start window.

Moving, the mean specific force is gravity plus the motion's own acceleration (a turn's centripetal part, a
walk's sway, braking): taken for gravity, it tilts the fused world by ``atan(a / g)``, 11 deg in a 2 m/s^2
turn, and every absolute odometry pose is then tied to that tilted world. A motion source that measures the
start's accelerations tells them apart: its poses and the IMU go through ``bootstrap.align``, the linear
alignment ``lio odom`` makes at its own moving start (position increments = velocity, gravity and the
preintegrated specific force), with

- odometry poses (``--odom``, ``--odom-topic``): their own rotations, in the odometry's world;
- else wheel speeds: poses dead-reckoned over the window from the gyro's rotations (from the base at the
  start) and the wheels' body velocity, in that start frame.

The alignment runs over twice the standing window (``standing_window_s``, 1 s: 2 s): its gravity term grows
with the square of the span, so a longer window tells gravity from the motion better.

What comes back is "up" and the velocity in base axes at the window's first instant, ``t0``: the alignment's at
its first pose, carried back to ``t0`` by the gyro (the velocity's change over that short stretch, at most
one odometry period, is left to the filter).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ...model.calibration import Extrinsics
from ...model.records import ImuBatch
from ..odometry.bootstrap import align
from ..imu import gyro_rotations, running_integral
from .timeline import Prepared

MIN_POSES = 4  # poses in the window: three increments at least, or velocity and gravity are not separated
MIN_SPAN_NS = 300_000_000  # their span: the gravity term grows with its square
WINDOW_FACTOR = 2  # the alignment's window, in standing windows (module docstring)
_BASE = Extrinsics(np.eye(4), np.eye(4))  # Prepared's IMU readings are already the base's (lever.py)


@dataclass(frozen=True)
class StartGravity:
    up_base: np.ndarray  # unit "up" in base axes at t0
    v_base: np.ndarray  # velocity in base axes at t0 (m/s)
    source: str  # "odometry" or "wheels"
    poses: int
    aligned: bool  # False: the alignment could not separate gravity and fell back to the mean specific force


def _imu_batch(prep: Prepared, t_a: int, t_b: int) -> ImuBatch:
    """The base-frame IMU readings from just before ``t_a`` to just after ``t_b``."""
    st = prep.imu.stamps_ns
    a = max(int(np.searchsorted(st, t_a, side="right")) - 1, 0)
    b = int(np.searchsorted(st, t_b, side="left")) + 1
    return ImuBatch("base", st[a:b], prep.imu_w_b[a:b], prep.imu_f_b[a:b])


def _odometry_poses(prep: Prepared, t_a: int, t_b: int):
    od = prep.odom
    if od is None or "odom" not in prep.use:
        return None
    sel = (od.stamps_ns >= t_a) & (od.stamps_ns <= t_b)
    return od.stamps_ns[sel], od.poses[sel]


def _wheel_poses(prep: Prepared, imu: ImuBatch, t_a: int, t_b: int):
    """Wheel poses over the window in the frame of the base at ``t_a``: the gyro's rotations (no bias: the
    window is short) and the body velocity's integral (trapezoids)."""
    w = prep.wheel
    if w is None or not ({"speed", "velocity"} & prep.use.get("wheel", set())):  # a yaw rate alone gives no path
        return None
    sel = np.flatnonzero((w.stamps_ns >= t_a) & (w.stamps_ns <= t_b) & np.isfinite(w.velocity_mps[:, 0]))
    if len(sel) < 2:
        return None
    stamps = w.stamps_ns[sel]
    times, Rs, _ = gyro_rotations(np.eye(3), np.zeros(3), imu, t_a, int(stamps[-1]), _BASE)
    R = Rs[np.clip(np.searchsorted(times, stamps), 0, len(Rs) - 1)]
    v = np.einsum("nij,nj->ni", R, np.nan_to_num(w.velocity_mps[sel]))
    p = running_integral((stamps - stamps[0]) * 1e-9, v)
    poses = np.repeat(np.eye(4)[None], len(sel), axis=0)
    poses[:, :3, :3], poses[:, :3, 3] = R, p
    return stamps, poses


def gravity_from_motion(prep: Prepared, t0: int, window_ns: int, gravity_mps2: float) -> StartGravity | None:
    """"Up" and the velocity in base axes at ``t0`` from the IMU aligned with the odometry poses (else the
    wheels) over ``WINDOW_FACTOR * window_ns``; None when neither covers it with enough poses (module
    docstring)."""
    if prep.imu is None or len(prep.imu) < 2:
        return None
    t_a = max(t0, int(prep.imu.stamps_ns[0]))
    t_b = min(t0 + WINDOW_FACTOR * window_ns, int(prep.imu.stamps_ns[-1]))
    imu = _imu_batch(prep, t0, t_b)
    for source, poses_of in (("odometry", lambda: _odometry_poses(prep, t_a, t_b)),
                             ("wheels", lambda: _wheel_poses(prep, imu, t_a, t_b))):  # the wheels only if needed
        found = poses_of()
        if found is None:
            continue
        stamps, poses = found
        if len(stamps) < MIN_POSES or stamps[-1] - stamps[0] < MIN_SPAN_NS:
            continue
        boot = align(stamps, poses, imu, _BASE, gravity_mps2=gravity_mps2, accel_bias=np.zeros(3),
                     gyro_bias=None if source == "odometry" else np.zeros(3))
        R_first = poses[0, :3, :3]  # base axes at the first pose: up, velocity; the gyro carries them to t0
        up_first, v_first = -(R_first.T @ boot.g_world) / np.linalg.norm(boot.g_world), R_first.T @ boot.v_start
        _, Rs, _ = gyro_rotations(np.eye(3), boot.gyro_bias, imu, t0, int(stamps[0]), _BASE)
        return StartGravity(Rs[-1] @ up_first, Rs[-1] @ v_first, source, len(stamps), boot.gravity_aligned)
    return None
