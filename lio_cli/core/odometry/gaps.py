"""Gaps in the input.

A LiDAR gap (no scan for longer than ``max_gap_s``) that the IMU covers, while the IMU state runs, is bridged
(``bridge``): the state is propagated across it, and the scan after it registered with full iterations and a gate
widened by how far a prediction drifts over that long (``bridge_gate_m``). A gap longer than ``max_bridge_s``, one
the IMU has a gap in too, or one without an IMU state restarts from the LiDAR (``bridge_refused`` says why).

An IMU gap (no sample for longer than ``MAX_IMU_GAP_NS``) within a scan's interval would prime the scan wrongly:
such a scan is registered LiDAR-only from yaw hypotheses (``blind``), kept out of the map, and the IMU state is
re-seeded from it keeping its biases and gravity (``imu_gap_step``). An IMU gap longer than ``max_gap_s`` drops the
IMU state instead; it starts again from LiDAR-only scans after the gap.
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np

from ...model.records import ImuBatch, PointCloud
from ..imu import NavState, imu_hole_ns
from .lidar_step import lidar_step
from .state import OdomState, ScanResult
from .tuning import (DRIFT_SIGMA_MPS, DRIFT_SIGMA_MPS2, GATE_M, MAX_BRIDGE_GATE_M, RESEED_SIGMA_M, RESEED_SIGMA_MPS,
                     RESEED_SIGMA_RAD)


def bridge_gate_m(gap_s: float) -> float:
    """Correspondence gate of the first scan after a bridged gap of ``gap_s``: the usual one plus 3 drifts."""
    drift_m = DRIFT_SIGMA_MPS * gap_s + 0.5 * DRIFT_SIGMA_MPS2 * gap_s**2
    return float(min(GATE_M + 3.0 * drift_m, MAX_BRIDGE_GATE_M))


def bridge_refused(has_state: bool, imu_window: Callable[[int], ImuBatch], t_prev: int, t_ref: int,
                   max_bridge_s: float) -> str | None:
    """Why a time gap cannot be bridged (words for the event), or None if it can; ``imu_window(t_prev)``: the IMU
    samples from there on, asked for only once the rest allows a bridge."""
    if not has_state:
        return "no IMU state to carry across it"
    if (t_ref - t_prev) * 1e-9 > max_bridge_s:
        return f"longer than max_bridge_s, {max_bridge_s:g} s"
    hole_ns = imu_hole_ns(imu_window(t_prev).stamps_ns, t_prev, t_ref)
    if hole_ns is not None:
        return f"the IMU has a {hole_ns * 1e-9:.3g} s gap in it too"
    return None


def reseeded(kept: NavState, t_ref: int, pose: np.ndarray, v: np.ndarray | None) -> NavState:
    """``kept`` moved to ``pose`` (and velocity ``v`` unless None) at ``t_ref``, its pose and velocity covariance
    widened; biases and gravity kept."""
    s = kept.copy()
    s.stamp_ns, s.R, s.p = t_ref, pose[:3, :3].copy(), pose[:3, 3].copy()
    if v is not None:
        s.v = v
    s.P[0:9, :] = 0.0
    s.P[:, 0:9] = 0.0
    s.P[0:9, 0:9] = np.diag([RESEED_SIGMA_RAD**2] * 3 + [RESEED_SIGMA_M**2] * 3 + [RESEED_SIGMA_MPS**2] * 3)
    return s


def imu_gap_step(o: OdomState, cloud: PointCloud, t_prev: int, t_ref: int, hole_ns: int) -> ScanResult | None:
    """An IMU-mode scan over an IMU gap: registered LiDAR-only and kept out of the map (it is a few degrees off); the
    IMU state is re-seeded from it (its pose, the mean velocity since the gap began), so the first scan after the
    gap is IMU-primed again."""
    kept, g_world = o.nav.state, o.nav.g_world
    if o.gaps.imu_gap_from is None:  # the gap's first scan: (last pose before it, its stamp, its event)
        event = o.event("imu gap", f"no IMU sample for {hole_ns * 1e-9:.3g} s")
        o.gaps.imu_gap_from = (o.track.last_pose, o.track.last_ns, event)
    gap_from = o.gaps.imu_gap_from
    pose0, t0, event = gap_from
    o.lose_imu_state()  # for lidar_step: LiDAR-only; the gap's start is kept
    o.gaps.imu_gap_from = gap_from
    if t0 is not None and (t_ref - t0) * 1e-9 > o.cfg.max_gap_s:  # too long to leave out of the map
        o.gaps.imu_gap_from = None
        event["reason"] += f"; after {(t_ref - t0) * 1e-9:.3g} s the IMU state starts again from LiDAR-only scans"
        return lidar_step(o, cloud, t_prev, t_ref)
    res = lidar_step(o, cloud, t_prev, t_ref, window=False, mapped=False)
    o.nav.g_world = g_world
    if res is None:  # skipped: the state stays where the last scan left it
        o.nav.state = kept
        return None
    v = None
    if not res.failed and t0 is not None and t_ref > t0:
        v = (res.pose[:3, 3] - pose0[:3, 3]) / ((t_ref - t0) * 1e-9)
    o.nav.state = reseeded(kept, t_ref, res.pose, v)
    scans = o.stats.scans - event["scan"] + 1
    event["reason"] = (f"no IMU sample for {hole_ns * 1e-9:.3g} s: {scans} scan{'s' * (scans > 1)} registered "
                       "LiDAR-only (yaw hypotheses around constant velocity), kept out of the map; the IMU state "
                       "re-seeded from them")
    return res
