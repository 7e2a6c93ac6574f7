"""The IMU-primed step: propagate the IMU state to the scan's reference instant, de-skew the scan by it, register
it from the prediction, check its geometry, correct the state; guards send a scan the state cannot explain to
``recovery`` and a scan over an IMU gap to ``gaps``."""

from __future__ import annotations

import time


from ...geometry import inv_pose, project_to_se2
from ...model.records import PointCloud
from ..imu import imu_hole_ns, propagate
from ..motion_compensation import constant_velocity_knots
from .gaps import imu_gap_step
from .guards import icp_cap, implausible, predicted_only, registration_failed, state_implausible, turning_slowly
from .priors import guess as prior_guess
from .recovery import doubted_scan, failed_registration
from .scan import degeneracy, finish, prepare
from .state import OdomState, ScanResult
from .updates import correct, track_clock, wheel_update


def imu_step(o: OdomState, cloud: PointCloud, t_prev: int, t_ref: int,
             bridge_gate_m: float | None = None) -> ScanResult | None:
    """One IMU-primed scan; ``bridge_gate_m``: the first scan after a bridged time gap, registered with this gate
    and full iterations."""
    st, cfg, nav, track, planar = o.stats, o.cfg, o.nav, o.track, o.settings.planar
    rc = cfg.registration
    tick = time.process_time()
    imu = o.imu_window(t_prev)
    hole_ns = imu_hole_ns(imu.stamps_ns, t_prev, t_ref)
    if hole_ns is not None:  # rates interpolated or held across it would prime the scan wrongly
        return imu_gap_step(o, cloud, t_prev, t_ref, hole_ns)
    o.gaps.imu_gap_from = None
    # propagate
    prop = propagate(nav.state, imu, t_ref, o.ext, noise=o.settings.imu_noise, planar=planar)
    st.imu_gaps += int(prop.gap)
    saved = nav.state
    nav.state = prop.state
    if cfg.use_wheel:
        wheel_update(nav.state, o.wheel, t_prev, t_ref, cfg.fusion, st)
    st.times_s["propagate"] += time.process_time() - tick
    # a slowly turning scan may take its prediction unregistered (a bridge: full iterations)
    slow = bridge_gate_m is None and turning_slowly(imu, t_prev, t_ref, nav.state.bg, rc)
    if predicted_only(slow, rc.slow_register_every, track, o.health.doubt, o.degeneracy.clear_scene,
                      0 if o.reg is None else o.reg.scans, st):
        result = finish(o, t_ref, nav.state.pose(), None, None, [], False)
        track.predicted_ns.add(t_ref)
        return result
    # de-skew
    dt_scan = (t_ref - t_prev) * 1e-9
    if o.settings.deskew == "imu":
        knots, knot_poses = prop.stamps_ns, prop.poses
    elif o.settings.deskew == "constant-velocity":
        knots, rel = constant_velocity_knots(track.last_delta, t_prev, t_ref)
        knot_poses = track.last_pose[None] @ rel
    else:
        knots = knot_poses = None
    points = prepare(o, cloud, knots, knot_poses, t_ref)
    if points is None:
        nav.state = saved  # the scan is skipped: keep the state where the last used scan left it
        return None
    # register from the prediction
    tick = time.process_time()
    guess = prior_guess(o, t_prev, t_ref)
    frame, source = o.reg.downsample(points)
    cap = None if bridge_gate_m is not None else icp_cap(slow, rc, o.clock)
    st.capped_icp_scans += int(cap is not None)
    measured = o.reg.register(source, guess, adaptive=bridge_gate_m is not None, gate_m=bridge_gate_m,
                              iterations=cap)
    st.registered(time.process_time() - tick)
    # geometry and guards
    dirs_b = degeneracy(o, points, nav.state.R)
    if planar:
        measured = project_to_se2(measured)
    if registration_failed(measured, guess, o.reg.empty, bridge_gate_m):
        return failed_registration(o, cloud, t_prev, t_ref, measured, guess, dirs_b)
    tick = time.process_time()
    o.health.doubt, reason = implausible(nav.state, measured, dirs_b, cfg.fusion, o.health.doubt)
    if o.health.doubt:  # the innovation is not believable: follow the LiDAR, keep velocity, biases and gravity
        st.times_s["fuse"] += time.process_time() - tick
        return doubted_scan(o, cloud, t_prev, t_ref, measured, guess, frame, dirs_b, reason, points)
    # correct the state
    pose = correct(nav.state, measured, dirs_b, dt_scan, cfg.fusion, o.ext.R_base_imu, planar)
    reason = reason or state_implausible(nav.state, cfg.max_speed_mps)
    if reason is None:
        nav.g_world = nav.state.g.copy()  # the latest gravity of a healthy state
        if cap is None:  # a capped registration leans on the IMU's timing: it cannot time it
            track_clock(o, t_ref, measured)
    st.times_s["fuse"] += time.process_time() - tick
    o.health.lost = 0
    result = finish(o, t_ref, pose, frame, inv_pose(guess) @ measured, dirs_b, False, points)
    if reason is not None:
        st.recoveries += 1
        o.event("recovery", reason + ": back to LiDAR-only scans")
        o.lose_imu_state()
    return result
