"""The LiDAR-only step: start-up window, recoveries, runs without an IMU, and how a lost track ends a run."""

from __future__ import annotations

import time

import numpy as np

from ...geometry import inv_pose, project_to_se2
from ...model.records import ImuBatch, PointCloud
from ..imu import imu_hole_ns
from .blind import register_blind
from .guards import count_lost
from .pose_checks import exceeds_jump, lean_on_prior, untouched
from .priors import lidar_prior
from .scan import degeneracy, finish, prepare
from .state import OdomState, ScanResult, WindowScan
from .tuning import (GYRO_PRIOR_GATE_M, GYRO_PRIOR_JUMP_M, GYRO_PRIOR_JUMP_RAD, MAP_RESTART_SCANS, MAX_MAP_RESTARTS,
                     UNKNOWN_SPEED_GATE_M, UNKNOWN_SPEED_SCANS, UNKNOWN_SPEED_SHIFT_M,
                     WHEEL_SPEED_HALF_WINDOW_NS)
from .wheel import wheel_speed


def imu_hole(o: OdomState, t_prev: int, t_ref: int) -> bool:
    """The scan's interval has an IMU gap (counted) where the IMU would otherwise prime it."""
    if not o.imu_ready():
        return False
    stamps = o.imu_window(t_prev).stamps_ns
    if not len(stamps) or stamps[0] > t_prev:
        return False  # before the IMU starts: no gap, nothing to prime with (a gap's end is not known online)
    hole = imu_hole_ns(stamps, t_prev, t_ref) is not None
    o.stats.imu_gaps += int(hole)
    return hole


def beyond_reach(o: OdomState, source: np.ndarray, guess: np.ndarray, gate: float) -> np.ndarray:
    """Where ICP starts before the speed is known (the guess's constant velocity may be a standstill that never
    was): a registration with a gate as wide as that speed is unknown, if it lands beyond ``gate`` of the guess,
    where a registration gated at ``gate`` cannot reach (nearer, the start-up window's slide catches a motion),
    or, in a pass without a start-up window (``gyro_only``), ``UNKNOWN_SPEED_SHIFT_M``; else the guess."""
    wide = o.reg.register(source, guess, adaptive=True, gate_m=max(gate, UNKNOWN_SPEED_GATE_M))
    reach = UNKNOWN_SPEED_SHIFT_M if o.settings.gyro_only else gate
    if np.isfinite(wide).all() and np.linalg.norm(wide[:3, 3] - guess[:3, 3]) > reach:
        return wide
    return guess


def lidar_step(o: OdomState, cloud: PointCloud, t_prev: int, t_ref: int, retry: bool = False,
               window: bool = True, mapped: bool = True) -> ScanResult | None:
    """Register one scan LiDAR-only. ``retry``: a scan the IMU prediction could not explain; return None (and change
    nothing) if it fails here too, since then the scan is bad, not the IMU state. ``window``: the scan may start the
    IMU state (it joins the start-up window, ``startup.due``). ``mapped``: the scan joins the map (unless it failed)."""
    st, planar = o.stats, o.settings.planar
    tick = time.process_time()
    imu_gap = imu_hole(o, t_prev, t_ref)  # held rates would prime it wrongly: constant velocity instead
    guess, knots, knot_poses, gyro_primed = lidar_prior(o, t_prev, t_ref, imu_gap)
    st.times_s["propagate"] += time.process_time() - tick
    jump_m = GYRO_PRIOR_JUMP_M
    if imu_gap and o.reg is not None and not o.reg.empty:  # no rotation prior: hypotheses
        tick = time.process_time()
        blind = register_blind(o, cloud, t_prev, t_ref, guess)
        if blind is None:
            return None
        points, frame, measured = blind
    else:
        points = prepare(o, cloud, knots, knot_poses, t_ref)
        if points is None:
            return None
        tick = time.process_time()
        frame, source = o.reg.downsample(points)
        gate = (o.cfg.registration.gyro_prior_gate_m or GYRO_PRIOR_GATE_M) if gyro_primed else None
        start = guess
        if gyro_primed and o.startup.bootstrap is None and st.lidar_only_scans < UNKNOWN_SPEED_SCANS:
            start = beyond_reach(o, source, guess, gate)
        measured = o.reg.register(source, start, adaptive=True, gate_m=gate)
        jump_m = GYRO_PRIOR_JUMP_M if start is guess else max(GYRO_PRIOR_JUMP_M, UNKNOWN_SPEED_GATE_M)
    st.registered(time.process_time() - tick)
    if planar:
        measured = project_to_se2(measured)
    failed = not o.reg.empty and (not np.isfinite(measured).all()
                                  or untouched(measured, guess)
                                  or (gyro_primed and exceeds_jump(measured, guess, jump_m, GYRO_PRIOR_JUMP_RAD)))
    if failed and retry:
        return None
    dirs_b = degeneracy(o, points, guess[:3, :3])
    pose = guess if failed else lean_on_prior(measured, guess, dirs_b)
    if planar:
        pose = project_to_se2(pose)
    st.lidar_only_scans += 1
    if failed:
        st.registration_failures += 1
        count_lost(o.health, o.cfg.max_lost_scans, st.scans, t_ref)
        health = o.health
        if o.reg.scans == 1 and health.lost >= MAP_RESTART_SCANS and health.map_restarts < MAX_MAP_RESTARTS:
            # the map's only scan matched none of the scans after it: that scan is the bad one (damaged, or
            # another world), so the map starts again from the next scan, the pose carried by the prior
            o.reg, health.map_restarts, o.startup.scans, o.startup.held = None, health.map_restarts + 1, [], []
            o.degeneracy.reset()  # a new scene: analysed at once
            o.event("map restarted", f"the map's first scan matched none of the {health.lost} after it")
    else:
        o.health.lost = 0
    keep = mapped and not failed
    result = finish(o, t_ref, pose, frame if keep else None, inv_pose(guess) @ measured if keep else None,
                    dirs_b, failed, points)
    if imu_gap:
        o.startup.scans, o.startup.held = [], []  # the IMU state starts from scans after the gap
    elif o.imu_ready() and not failed and window and not o.settings.gyro_only:
        if o.startup.first_f_base is None:
            imu = ImuBatch.concat(o.imu.batches)
            bias = o.settings.bias_prior[1]
            ba = np.zeros(3) if bias is None else np.asarray(bias, dtype=np.float64)
            o.startup.first_f_base = o.ext.R_base_imu @ (imu.accel_mps2.mean(axis=0) - ba)
        speed = wheel_speed(o.wheel, t_ref, WHEEL_SPEED_HALF_WINDOW_NS) if o.cfg.use_wheel else np.nan
        o.startup.scans.append(WindowScan(t_prev, t_ref, pose, speed, cloud, len(o.track.poses) - 1))
        o.startup.due = True
    return result
