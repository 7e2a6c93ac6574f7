"""``fuse(inputs, options)``: the one entry point of the estimation core of ``lio fuse``."""

from __future__ import annotations

import time
from dataclasses import replace

import numpy as np

from ...geometry import so3_exp_one
from .choose import EstimatorChoice, choose_estimator
from .complementary import run_complementary
from .ekf3d import Ekf3d
from . import graph
from .gps_heading import heading_prefix_end, prefix_without_gps, yaw_onto, yaw_velocity_onto
from .initial import Start, initial_state
from .inputs import FuseInputs, FuseOptions
from .planar import PlanarEkf, run_planar
from .result import FuseResult, anchor_to_origin
from .smoother import rts_smooth
from .state3d import P_, R_, V_
from .timeline import Prepared, planar_use, prepare

_EKF_XY = slice(P_.start, P_.start + 2)  # x, y of the 3D filter's nominal state


def fuse(inputs: FuseInputs, options: FuseOptions | None = None) -> FuseResult:
    """Fuse the sources into one trajectory at the output stamps (see ``FuseOptions``).

    Raises ``InputError`` (no motion source, nothing usable, sources on different clocks) or
    ``ConfigError`` (an option no run can use) with one line.
    """
    o = options or FuseOptions()
    t_start = time.perf_counter()
    prep, choice = _prepare_and_choose(inputs, o)
    o = replace(o, estimator=choice.name)
    if o.estimator == "planar":
        result = run_planar(prep, o, _start(prep, o, PlanarEkf, slice(0, 2)))
    elif o.estimator == "complementary":  # the GPS heading pass needs a filter with knots: the EKF's
        result = run_complementary(prep, o, _start(prep, o, Ekf3d, _EKF_XY))
    else:
        result = _run_ekf3d(prep, o)
    result.info.update(_common_info(prep, o))
    result.info.update(estimator_reason=choice.reason, estimator_evidence=choice.evidence)
    result.info["run_time_s"] = time.perf_counter() - t_start
    return result


def _prepare_and_choose(inputs: FuseInputs, o: FuseOptions) -> tuple[Prepared, EstimatorChoice]:
    """The prepared sources and the estimator: the one given, or (``auto``) the one the data asks for."""
    if o.estimator != "auto":
        return prepare(inputs, o), EstimatorChoice(o.estimator, "given with --estimator", {})
    prep = prepare(inputs, replace(o, estimator="ekf"))
    choice = choose_estimator(prep)
    if choice.name == "planar":
        planar_use(prep.use)
    return prep, choice


def pick_estimator(inputs: FuseInputs, options: FuseOptions) -> EstimatorChoice:
    """The estimator ``fuse`` would run on these inputs and why (for a caller that fuses in pieces)."""
    return _prepare_and_choose(inputs, options)[1]


def _common_info(prep: Prepared, o: FuseOptions) -> dict:
    return {
        "use": {k: sorted(v) for k, v in prep.use.items()},
        "span_ns": [prep.t0_ns, prep.t1_ns],
        "covered_s": sum(b - a for a, b in prep.coverage) * 1e-9,
        "motion_gaps": len(prep.coverage) - 1,
        "outputs_dropped_outside_data": prep.out_dropped,
        "notes": list(prep.notes),
    }


def _start(prep: Prepared, o: FuseOptions, filter_cls, xy: slice) -> Start:
    """The initial state; with GPS and no absolute heading, its yaw from a GPS-free first pass."""
    start = initial_state(prep, o.standing_window_ns, o.gravity_mps2, o.noise)
    if "gps" not in prep.use or start.yaw_from != "start":
        return start
    t_end = heading_prefix_end(prep)
    if t_end is None:
        start.reason += "; GPS never spread enough to give the heading: yaw zero at the start"
        return start
    # a moving start nothing but the IMU measures: the pass started at rest, the fit gives the velocity
    unmeasured = not start.standing and prep.wheel is None and prep.odom is None
    knots = filter_cls(prefix_without_gps(prep, t_end), replace(o, smooth=False), start).run()
    k = np.searchsorted(prep.gps.stamps_ns, knots["t_ns"])
    ok = prep.gps.accepted[k]
    path, fixes = knots["x_filt"][ok][:, xy], prep.gps.position_enu_m[k[ok], :2]
    if unmeasured:
        yaw, w = yaw_velocity_onto(path, fixes, (knots["t_ns"][ok] - prep.t0_ns) * 1e-9)
    else:
        yaw = yaw_onto(path, fixes)
    Rz = so3_exp_one(np.array([0.0, 0.0, yaw]))
    start.R, start.v, start.yaw_from = Rz @ start.R, Rz @ start.v, "gps"
    start.reason += f"; heading {np.degrees(yaw):.1f} deg from GPS over the first {len(k)} fixes"
    if unmeasured:
        start.v[:2] += w
        start.reason += f", with the start velocity ({np.hypot(*w):.2f} m/s horizontal)"
    return start


def _run_ekf3d(prep: Prepared, o: FuseOptions) -> FuseResult:
    start = _start(prep, o, Ekf3d, _EKF_XY)
    if o.smooth and graph.applies(prep):  # the factor graph; RTS below for a filter without an accelerometer
        return graph.smooth_graph(prep, o, start)
    ekf = Ekf3d(prep, o, start)
    knots = ekf.run()
    x, P = knots["x_filt"], knots["P_filt"]
    if o.smooth and len(x):
        x, P = rts_smooth(knots, ekf.boxplus, ekf.boxminus)
    sel = knots["output"]
    cov = None
    if o.smooth:
        x, P = x[sel], P[sel]
        if o.want_covariance:
            cov = P[:, ekf.cov_index][:, :, ekf.cov_index]
    elif o.want_covariance:
        cov = P  # already the pose block, in COVARIANCE_LAYOUT order
    poses = np.zeros((len(x), 4, 4))
    if len(x):
        poses[:, :3, :3] = x[:, R_].reshape(-1, 3, 3)
        poses[:, :3, 3] = x[:, P_]
        poses[:, 3, 3] = 1.0
    s = ekf.start
    info = {"model": ekf.L.model, "start": s.reason, "world_yaw_from": s.yaw_from,
            "odom_mode": next(iter(prep.use.get("odom", ())), None)}
    if o.smooth:
        info["smoother"] = {"kind": "rts", "why": "no accelerometer in use: the factor graph's IMU factors need it"}
    return FuseResult(knots["t_ns"][sel], anchor_to_origin(poses), cov, x[:, V_] if len(x) else None, "ekf",
                      o.smooth, prep.reports, info)
