"""``fuse(inputs, options)``: the one entry point of the estimation core of ``lio fuse``."""

from __future__ import annotations

import copy
import time
from dataclasses import replace
from functools import partial

import numpy as np

from ...errors import LioError
from .choose import EstimatorChoice, choose_estimator
from .complementary import run_complementary
from .ekf3d import Ekf3d
from . import accel_check, agreement, grade, graph, heave, level, rest, shape
from .graph import wheels as graph_wheels
from .graph.keyframes import with_outputs
from .gps_heading import (heading_prefix_end, prefix_without_gps, tried_headings, turned, yaw_onto,
                          yaw_velocity_onto)
from .initial import Start, initial_state
from .inputs import FuseInputs, FuseOptions
from .pieces import bias_sigma, filtered_handover, state_handover
from .planar import PlanarEkf
from .rts_planar import run_planar
from .result import FuseResult, anchor_to_origin, enu_origin
from .smoother import rts_smooth
from .state3d import B_, BA_, P_, R_, V_
from .gyro_gaps import say_gyro_gaps
from .timeline import Prepared, planar_use, prepare

_EKF_XY = slice(P_.start, P_.start + 2)  # x, y of the 3D filter's nominal state


def fuse(inputs: FuseInputs, options: FuseOptions | None = None) -> FuseResult:
    """Fuse the sources into one trajectory at the output stamps (see ``FuseOptions``).

    Raises ``InputError`` (no motion source, nothing usable, sources on different clocks) or
    ``ConfigError`` (an option no run can use) with one line.
    """
    o = given = options or FuseOptions()
    t_start = time.perf_counter()
    prep, choice = _prepare_and_choose(inputs, o)
    o = replace(o, estimator=choice.name)
    if o.smooth and _graph_smooths(prep, o.estimator):
        result, prep = _run_graph(prep, o)
    else:
        result = _run_filter(prep, o)
    if o.smooth and o.test_gps_shape and shape.applies(prep, o.estimator):
        result = _shape_without_gps(inputs, given, prep, result)
    result.info.update(_common_info(prep, o))
    if result.estimator == "complementary":  # it takes no zero rate at rest
        result.info["rest"] = None
    if {"heave", "level"} & set(result.info):  # the planar filter leaves the accelerometer out; these came from it
        result.info["use"]["imu"] = sorted({*result.info["use"].get("imu", ()), "accel"})
    result.info.update(estimator_reason=choice.reason, estimator_evidence=choice.evidence)
    result.info["run_time_s"] = time.perf_counter() - t_start
    return result


def _shape_without_gps(inputs: FuseInputs, o: FuseOptions, prep: Prepared, fused: FuseResult) -> FuseResult:
    """The run without GPS placed on the fixes, or the GPS-fused ``fused``, as ``agreement`` judges them: asked
    where the claim looks optimistic, the IMU verified the wheels or backs their speed (for the planar filter or,
    without odometry, the 3D one, at the cost of the second, GPS-free run)."""
    optimistic = agreement.optimistic(prep.gps, fused)
    verified = prep.wheels_verified
    if not (optimistic or verified or agreement.wheel_speed_backed(prep.wheel_check)):
        return fused
    free = _without_gps(inputs, o)
    if free is None:  # the sources without GPS do not make a run: the GPS-fused one stands
        return fused
    return agreement.judged(prep.gps, prep.notes, fused, free, optimistic or verified)


def _without_gps(inputs: FuseInputs, o: FuseOptions) -> FuseResult | None:
    """The run on the same options without GPS; None where the other sources do not make one."""
    use = None if o.use is None else {k: set(v) for k, v in o.use.items() if k != "gps"}
    try:
        return fuse(replace(inputs, gps=None), replace(o, use=use))
    except LioError:
        return None


def _prepare(inputs: FuseInputs, o: FuseOptions) -> Prepared:
    """``prepare``, and a note where the odometry's scale is off the wheels' beyond a radius error."""
    prep = prepare(inputs, o)
    prep.rest = rest.rest_spans(prep, o.gravity_mps2)
    note = graph_wheels.odometry_scale_note(prep.wheel, prep.odom)
    if note:
        prep.notes.append(note)
    return prep


def _prepare_and_choose(inputs: FuseInputs, o: FuseOptions, check: bool = True) -> tuple[Prepared, EstimatorChoice]:
    """The prepared sources and the estimator: the one given, or (``auto``) the one the data asks for. When
    smoothing with an accelerometer the selection keeps it whatever the filter (the factor graph uses it). The
    accelerometer first checks the wheels (``accel_check.check``), unless ``check`` is False (the choice alone)."""
    if o.estimator not in ("auto", "planar") and not o.smooth:
        prep = _prepare(inputs, o)
        if check:
            accel_check.check(prep, o, o.estimator)
        say_gyro_gaps(prep, o.estimator)
        return prep, EstimatorChoice(o.estimator, "given with --estimator", {})
    prep = _prepare(inputs, replace(o, estimator="ekf"))
    given = o.estimator != "auto"
    measured = partial(accel_check.scale_measured, prep, o)  # asked only where it decides
    agrees = partial(graph_wheels.odometry_agreement, prep.wheel, prep.odom)
    choice = EstimatorChoice(o.estimator, "given with --estimator", {}) if given else \
        choose_estimator(prep, measured, agrees)
    if o.estimator == "planar" and (data := choose_estimator(prep, measured, agrees)).name != "planar":  # told
        choice = EstimatorChoice("planar", f"given with --estimator, where the data ask for the 3D filter: "
                                           f"{data.reason}", {})
    if check:
        accel_check.check(prep, o, choice.name)
    graph_runs = o.smooth and _graph_smooths(prep, choice.name)
    if choice.name == "planar" and not graph_runs:
        prep.heave_accel = "accel" in prep.use.get("imu", ())
        planar_use(prep.use)
        if choice.evidence.get("wheels_agree_with_odometry") and (o.use is None or o.default_use) \
                and prep.use.get("odom") == {"pose"}:  # its increments: the wheels it agrees with hold the path
            prep.use["odom"] = {"delta"}
    say_gyro_gaps(prep, choice.name, graph_runs)
    return prep, choice


def graph_smooths(use: dict, estimator: str) -> bool:
    """Whether smoothing runs the factor graph for this selection: with the accelerometer, whatever the filter,
    except the planar filter without GPS (IMU + wheels, and odometry the wheels agree with: ``choose``), where the
    graph measured no better than the planar filter itself and its RTS pass (docs/benchmarks.md); the planar RTS
    pass smooths those."""
    imu_ok = {"gyro", "accel"} <= set(use.get("imu", ()))
    return imu_ok and (estimator != "planar" or "gps" in use)


def _graph_smooths(prep: Prepared, estimator: str) -> bool:
    return graph.applies(prep) and graph_smooths(prep.use, estimator)


def _run_filter(prep: Prepared, o: FuseOptions) -> FuseResult:
    """The chosen filter (with the RTS pass under ``smooth`` for the two EKFs)."""
    if o.estimator == "planar":
        up = level.up_directions(prep) if level.applies(prep) else None
        prep.heading_offset = None if up is None else level.heading_rate_offset(prep, up)
        result = run_planar(prep, o, _start(prep, o, PlanarEkf, slice(0, 2)))
        if o.smooth and "rts_refused" in result.info:
            why = result.info.pop("rts_refused").removeprefix("smoother: ")
            result.info["smoother"] = {"kind": None, "why": why}
            prep.notes.append(f"smoother: {why}: the planar filter's trajectory kept, unsmoothed (odometry increments, "
                              "odom:delta, can do this; as poses, odom:pose, they smooth)")
        elif o.smooth:
            result.info["smoother"] = {"kind": "rts", "why": "the planar filter without GPS (IMU + wheels, beside "
                                                             "odometry they agree with, or without an "
                                                             "accelerometer): its RTS pass"}
            pitch_grade, grade_info = (None, None) if up is None else grade.estimate(prep, up, o.gravity_mps2)
            heave.lift(prep, result, pitch_grade)
            level.lift(prep, result, up, pitch_grade)
            if grade_info is not None and "level" in result.info:
                result.info["level"]["grade"] = grade_info
        return result
    if o.estimator == "complementary":  # the GPS heading pass needs a filter with knots: the EKF's
        result = run_complementary(prep, replace(o, smooth=False), _start(prep, o, Ekf3d, _EKF_XY))
        if o.smooth:
            result.info["smoother"] = {"kind": None, "why": "the complementary filter has no smoother and the "
                                                            "factor graph needs the accelerometer"}
        return result
    return _run_ekf3d(prep, o)


def _run_graph(prep: Prepared, o: FuseOptions) -> tuple[FuseResult, Prepared]:
    """The factor graph over the whole log, whatever the filter; where its guard refuses it (its fallback is the
    3D filter) and another filter was chosen, that filter's trajectory instead (planar: with its RTS pass)."""
    reports, notes = copy.deepcopy(prep.reports), list(prep.notes)
    seed = _planar_seed(prep, o) if o.estimator == "planar" else None
    result = graph.smooth_graph(prep, o, _start(prep, o, Ekf3d, _EKF_XY), seed)
    info = result.info["smoother"]
    info["initial_filter"] = "ekf"
    refused = info.get("fallback")
    if o.estimator == "ekf" or refused is None:
        result.estimator = o.estimator
        return result, prep
    use = {k: set(v) for k, v in prep.use.items()}
    if o.estimator == "planar":
        planar_use(use)
    gap_said = prep.gyro_gaps.said if prep.gyro_gaps is not None else None
    kept = replace(prep, use=use, reports=reports,
                   notes=[n for n in notes if n != gap_said] + [
                       f"smoother: the {o.estimator} filter's trajectory kept: the factor graph explained the "
                       f"measurements worse than the 3D filter it starts from ({refused})"])
    kept.heave_accel = "accel" in prep.use.get("imu", ())  # the planar filter's heading, heave and tilt (level)
    if gap_said is not None:  # the gaps as the kept filter bridged them, not the graph
        say_gyro_gaps(kept, o.estimator)
    fallback = _run_filter(kept, o)
    fallback.info["smoother"] = {**info, "kept": fallback.info.get("smoother", {}).get("kind") or "filter"}
    return fallback, kept


def whole_log_options(inputs: FuseInputs, options: FuseOptions) -> tuple[EstimatorChoice, FuseOptions]:
    """The estimator ``fuse`` would run and the options every piece of the log is then fused with: that estimator
    and the wheels' yaw rate weighed on the whole log (``wheel_yaw``), so every piece uses and reports the same."""
    prep, choice = _prepare_and_choose(inputs, options, check=False)
    use = options.use
    if use is not None and "odom" in use and "odom" in prep.use:  # the mode the estimator took (increments)
        use = {**use, "odom": set(prep.use["odom"])}
    return choice, replace(options, estimator=choice.name, wheel_yaw=prep.wheel_yaw_weighed, use=use)


def judge_gps(inputs: FuseInputs, options: FuseOptions) -> agreement.GpsJudge | None:
    """The whole log's judge of the GPS fixes for a log fused in pieces with ``options`` (those of
    ``whole_log_options``): the fixes as the whole log assesses them (its jumps), and whether ``fuse`` would test
    their agreement (``tests``: smoothing GPS beside IMU + wheels, without odometry or beside odometry the planar
    filter runs with, ``shape.applies``). None without GPS in use."""
    prep, _ = _prepare_and_choose(inputs, options, check=False)
    if prep.gps is None or "gps" not in prep.use:
        return None

    def wheels() -> tuple[bool, bool]:  # the wheel check ``fuse`` makes on the whole log
        checked, _ = _prepare_and_choose(inputs, options)
        return checked.wheels_verified, agreement.wheel_speed_backed(checked.wheel_check)

    notes = prep.reports["gps"].notes
    tests = bool(options.smooth and options.test_gps_shape and shape.applies(prep, options.estimator))
    return agreement.GpsJudge(prep.gps, wheels, tests, {k: notes[k] for k in agreement.WHOLE_LOG_NOTES if k in notes})


def _planar_seed(prep: Prepared, o: FuseOptions):
    """Keyframe stamps -> the planar filter's x, y, yaw and speed there (the graph's start where planar was
    chosen: the 3D filter can be far off on such logs, e.g. a moving start with a rotated IMU, 6.7 m vs 0.18 m)."""
    use = {k: set(v) for k, v in prep.use.items()}
    planar_use(use)
    alone = replace(prep, use=use, reports=copy.deepcopy(prep.reports), notes=[])
    po = replace(o, smooth=False, want_covariance=False)
    start = _start(alone, po, PlanarEkf, slice(0, 2))

    def at(stamps: np.ndarray) -> np.ndarray:
        knots = PlanarEkf(with_outputs(alone, stamps), po, start).run()
        sel = knots["output"]
        x = knots["x_filt"][sel]
        k = np.minimum(np.searchsorted(knots["t_ns"][sel], stamps), len(x) - 1)
        return x[k][:, [0, 1, 2, 3]]

    return at


def _common_info(prep: Prepared, o: FuseOptions) -> dict:
    return {
        "use": {k: sorted(v) for k, v in prep.use.items()},
        "span_ns": [prep.t0_ns, prep.t1_ns],
        "covered_s": sum(b - a for a, b in prep.coverage) * 1e-9,
        "motion_gaps": len(prep.coverage) - 1,
        "rest": rest.summary(prep.rest),
        "outputs_dropped_outside_data": prep.out_dropped,
        "outputs_in_gyro_gaps": prep.gyro_gaps.outputs if prep.gyro_gaps is not None else 0,
        "notes": list(prep.notes),
        "wheel_check": prep.wheel_check,
        "wheel_yaw_check": prep.wheel_yaw_check,
    }


def _start(prep: Prepared, o: FuseOptions, filter_cls, xy: slice) -> Start:
    """The initial state (the one handed over, ``o.start``); with GPS and no absolute heading, its yaw from a
    GPS-free first pass."""
    if o.start is not None:
        return replace(o.start)
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
        yaw, w, tried = tried_headings(prep, replace(o, smooth=False), filter_cls, xy, start, t_end,
                                       (path, fixes, (knots["t_ns"][ok] - prep.t0_ns) * 1e-9), yaw)
    else:
        yaw = yaw_onto(path, fixes)
    turned(start, yaw)
    start.reason += f"; heading {np.degrees(yaw):.1f} deg from GPS over the first {len(k)} fixes"
    if unmeasured:
        start.v[:2] += w
        start.reason += f", with the start velocity ({np.hypot(*w):.2f} m/s horizontal){tried}"
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
    bg_sigma = bias_sigma(ekf.handed, "gps" in prep.use, o.noise.init_gyro_bias_sigma_radps)
    if ekf.handed is not None and not o.smooth:  # the next piece's start: the filter's state there
        info["handover"] = filtered_handover(ekf.handed, o.noise.init_velocity_sigma_mps, bg_sigma)
    elif ekf.handed is not None and len(x):  # smoothed: its state at the output there
        states = {"R": x[:, R_].reshape(-1, 3, 3), "v": x[:, V_], "bg": x[:, B_], "ba": x[:, BA_]}
        info["handover"] = state_handover(knots["t_ns"][sel], states, o.handover_ns, o.noise.init_velocity_sigma_mps,
                                          bg_sigma)
    origin = enu_origin(poses, None if ekf.gps_offset is None else -ekf.gps_offset)
    return FuseResult(knots["t_ns"][sel], anchor_to_origin(poses), cov, x[:, V_] if len(x) else None, "ekf",
                      o.smooth, prep.reports, info, origin)
