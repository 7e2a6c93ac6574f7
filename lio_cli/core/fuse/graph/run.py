"""The graph smoother's run: filter pass, chunked solve, guard, output (see the package docstring)."""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import replace

import gtsam
import numpy as np

from ....geometry import interpolate_poses, yaw_of
from ..ekf3d import Ekf3d
from ..initial import Start
from ..inputs import FuseOptions
from ..pieces import bias_sigma, state_handover
from ..result import FuseResult, anchor_to_origin, enu_origin
from ..state3d import BA_, B_, P_, R_, V_, Layout, initial_estimate
from ..timeline import Prepared
from . import guard, height
from .factors import ChunkGraph, Measurements, nav
from .imu import Segments, imu_params
from .keyframes import filter_options, keyframe_stamps, with_outputs
from .output import at_outputs
from .solve import Prior, seam_prior, solve

MIN_VARIANCE = 1e-10  # the start's "known exactly" variances (1e-12) kept solvable
# accelerometer noise density multipliers tried in turn until the guard accepts: a real accelerometer noisier
# than its density (jackal.bag's) would otherwise draw the graph off
ACCEL_NOISE_SCALES = (1.0, 10.0)
SEAM_VELOCITY_SIGMA = 0.2  # m/s: a chunk's prior on its first velocity (its IMU and wheels find it again)
# with odometry, the graph starts from its poses (the filter's states moved onto them): from a filter a bad source
# (wheel scale, slips) drew off, LM stops at its 40 iterations far from the optimum it reaches from there
ODOM_SEED = True


Seed = Callable[[np.ndarray], np.ndarray]  # keyframe stamps -> (K, 4) x, y, yaw, forward speed of a planar filter


def smooth_graph(prep: Prepared, o: FuseOptions, start: Start, seed: Seed | None = None) -> FuseResult:
    """The smoothed trajectory at ``prep.out_stamps`` (the filter's where the guard refuses the graph's).
    ``seed``: the chosen planar filter's states, which replace the 3D filter's horizontal position, heading and
    horizontal velocity as the graph's starting values and as what its guard compares with."""
    kt = keyframe_stamps(prep)
    out = prep.out_stamps
    stamps = np.union1d(kt, out)
    ekf = Ekf3d(with_outputs(prep, stamps), filter_options(o), start)
    knots = ekf.run()
    sel = knots["output"]
    t, x = knots["t_ns"][sel], knots["x_filt"]
    at_k, at_o = np.searchsorted(t, kt), np.searchsorted(t, out)
    states = {"R": x[at_k, R_].reshape(-1, 3, 3), "p": x[at_k, P_], "v": x[at_k, V_], "bg": x[at_k, B_],
              "ba": x[at_k, BA_]}
    if seed is not None:
        _reseed(states, seed(kt))
    meas = Measurements(prep, kt, o.noise)
    filtered = {k: v.copy() for k, v in states.items()}  # what the guard compares with
    if ODOM_SEED and len(meas.odom_k) > 1:  # increments (beside GPS): their shape fitted onto the filter's track
        _seed_from_odom(states, meas, fit="pose" not in prep.use["odom"])
    P_k = knots["P_filt"][at_k]
    bias_sigmas = np.r_[np.full(3, o.noise.init_accel_bias_sigma_mps2), np.full(3, o.noise.init_gyro_bias_sigma_radps)]
    seam = lambda sol, j, k: seam_prior(sol, j, _pose_cov(P_k[k], states["R"][k]), SEAM_VELOCITY_SIGMA,  # noqa: E731
                                        bias_sigmas)
    iterations, tries, seg = 0, [], Segments(prep, kt)
    for scale in ACCEL_NOISE_SCALES:  # the accelerometer trusted less when the graph explained the rest worse
        params = imu_params(replace(o.noise, accel_noise_density=scale * o.noise.accel_noise_density), o.gravity_mps2)
        cg = ChunkGraph(meas, seg, params, states)
        if cg.level is not None:  # start at the prior's height: from the odometry's drifted one LM stalls
            states["p"][:, 2], states["v"][:, 2] = states["p"][0, 2], 0.0
        smoothed, stats = solve(cg, len(kt), _start_prior(prep, o, start, ekf.L), seam)
        iterations += stats.iterations
        before, after = guard.residuals(meas, filtered), guard.residuals(meas, smoothed)
        why = guard.verdict(before, after, guard.noise_levels(meas), guard.ratios(meas))
        tries.append(why)
        if why is None:
            break
    info = {"kind": "factor_graph", "solver": "levenberg_marquardt", "keyframes": len(kt), "chunks": stats.chunks,
            "iterations": iterations, "initial_error": stats.initial_error, "final_error": stats.final_error,
            "imu_bridged": cg.bridged, "accel_noise_scale": scale, "residuals_filter": before, "residuals_smoothed": after, "fallback": why,
            "refused": [t for t in tries if t]}
    if cg.rested:
        info["rest_intervals"] = cg.rested
    if cg.wheel_info() is not None:
        info["wheel"] = cg.wheel_info()
    if meas.odom_spin is not None:  # the odometry increments' rotation scatter about the gyro's (odom_spin)
        info["odom_rotation_scatter_rad"] = float(f"{meas.odom_spin:.3g}")
    if cg.level is not None:
        info["height"] = {"model": height.MODEL, "sigma_m": round(cg.level.sigma_m, 4), "priors": cg.levelled,
                          "evidence": cg.level.evidence}
    cov = knots["P_filt"][at_o] if o.want_covariance and len(knots["P_filt"]) else None
    if why is not None:
        prep.notes.append(f"smoother: the filter's trajectory kept, the factor graph's was worse ({why})")
        poses = np.zeros((len(out), 4, 4))
        poses[:, :3, :3] = x[at_o, R_].reshape(-1, 3, 3)
        poses[:, :3, 3] = x[at_o, P_]
        poses[:, 3, 3] = 1.0
        vel = x[at_o, V_]
    else:
        poses, vel = at_outputs(Segments(prep, np.union1d(kt, out)), kt, smoothed, params, out)
    s = ekf.start
    result_info = {"model": ekf.L.model, "start": s.reason, "world_yaw_from": s.yaw_from,
                   "odom_mode": next(iter(prep.use.get("odom", ())), None), "smoother": info}
    if o.handover_ns is not None and len(kt):  # the next piece's start: the graph's state, or the filter's
        bg_sigma = bias_sigma(ekf.handed, "gps" in prep.use, o.noise.init_gyro_bias_sigma_radps)
        result_info["handover"] = state_handover(kt, smoothed if why is None else filtered, o.handover_ns,
                                                 SEAM_VELOCITY_SIGMA, bg_sigma)
    if why is None:  # the fixes' world about the first fix of the keyframes' span (``gps.attach_fixes``)
        world = meas.gps_origin_m if len(meas.gps_k) else None
    else:
        world = None if ekf.gps_offset is None else -ekf.gps_offset
    return FuseResult(out, anchor_to_origin(poses), cov, vel, "ekf", True, prep.reports, result_info,
                      enu_origin(poses, world))


def _reseed(states: dict[str, np.ndarray], planar: np.ndarray) -> None:
    """The 3D filter's keyframe states with a planar filter's x, y, heading and horizontal velocity (its tilt,
    height, vertical velocity and biases kept), in place."""
    d = planar[:, 2] - yaw_of(states["R"])
    c, s = np.cos(d), np.sin(d)
    Rz = np.zeros((len(d), 3, 3))
    Rz[:, 0, 0], Rz[:, 0, 1], Rz[:, 1, 0], Rz[:, 1, 1], Rz[:, 2, 2] = c, -s, s, c, 1.0
    states["R"] = Rz @ states["R"]
    states["p"] = np.column_stack([planar[:, 0], planar[:, 1], states["p"][:, 2]])
    states["v"] = np.column_stack([planar[:, 3] * np.cos(planar[:, 2]), planar[:, 3] * np.sin(planar[:, 2]),
                                   states["v"][:, 2]])


def _seed_from_odom(states: dict[str, np.ndarray], meas: Measurements, fit: bool = False) -> None:
    """The keyframe states moved rigidly onto the odometry's poses (interpolated, in the world the factors tie
    them to; held at the nearest end outside their span), velocity from the moved positions, in place."""
    od, kt = meas.prep.odom, meas.kt
    t_od = od.stamps_ns[meas.odom_idx]
    T_w = meas.odom_world(states) @ interpolate_poses(t_od, od.poses[meas.odom_idx], kt)
    T_f = np.tile(np.eye(4), (len(kt), 1, 1))
    T_f[:, :3, :3], T_f[:, :3, 3] = states["R"], states["p"]
    if fit:
        T_w = _yaw_fit(T_w, T_f) @ T_w
    D = T_w @ np.linalg.inv(T_f)
    inside = np.flatnonzero((kt >= t_od[0]) & (kt <= t_od[-1]))
    D[: inside[0]], D[inside[-1] + 1:] = D[inside[0]], D[inside[-1]]
    T = D @ T_f
    states["R"], states["p"] = T[:, :3, :3], T[:, :3, 3]
    states["v"] = np.gradient(states["p"], (kt - kt[0]) * 1e-9, axis=0) if len(kt) > 1 else states["v"]


def _yaw_fit(A: np.ndarray, B: np.ndarray) -> np.ndarray:
    """The rotation about z and translation moving poses A's positions onto B's in least squares (4x4)."""
    a, b = A[:, :2, 3], B[:, :2, 3]
    ma, mb = a.mean(0), b.mean(0)
    H = (a - ma).T @ (b - mb)
    th = np.arctan2(H[0, 1] - H[1, 0], H[0, 0] + H[1, 1])
    c, s = np.cos(th), np.sin(th)
    T = np.eye(4)
    T[:2, :2] = [[c, -s], [s, c]]
    T[:2, 3] = mb - T[:2, :2] @ ma
    T[2, 3] = float(np.mean(B[:, 2, 3] - A[:, 2, 3]))
    return T


def _pose_cov(P: np.ndarray, R: np.ndarray) -> np.ndarray:
    """The filter's pose covariance (COVARIANCE_LAYOUT: world position, base rotation) in Pose3's tangent
    (base rotation, base translation)."""
    J = np.zeros((6, 6))
    J[0:3, 3:6] = np.eye(3)
    J[3:6, 0:3] = R.T
    C = J @ P @ J.T
    return 0.5 * (C + C.T) + np.eye(6) * MIN_VARIANCE


def _start_prior(prep: Prepared, o: FuseOptions, start: Start, L: Layout) -> Prior:
    """The filter's first state and covariance as the graph's prior on its first keyframe."""
    x, P = initial_estimate(start, L, o.noise, prep)
    d = np.maximum(np.diag(P), MIN_VARIANCE)
    x = np.asarray(x)
    return Prior(nav(x[R_].reshape(3, 3), x[P_]), x[V_], gtsam.imuBias.ConstantBias(x[BA_], x[B_]),
                 np.diag(d[0:6]), np.diag(d[6:9]), np.diag(np.r_[d[12:15], d[9:12]]))
