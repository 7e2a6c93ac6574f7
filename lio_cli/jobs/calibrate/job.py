"""The ``calibrate`` job: estimate, from one log, the calibration every other command reads with ``--calib``.

``CalibrateJob`` (log, output YAML, configuration, optional Allan plot folder and Kalibr file) ->
``run_calibrate`` -> ``CalibrateResult`` (the calibration, the table of values / 1-sigmas / differences from
the reference, the skipped items with their reasons, metrics) -> ``write_calibrate``. Every output location is
checked first; the log is read in one pass gathering the IMU and wheel arrays while the LiDAR-only odometry runs
(``passes``), the estimators run (``estimate``), gyro-primed passes sharpen the trajectory and they run again.
Bad input raises before anything is written; ``write_calibrate`` then writes the YAML, its ``.metrics.json``
and ``.config.yaml`` (and the Kalibr file and the plot), each atomically.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from ...config import with_overrides
from ...config.calibrate import CalibrateConfig, parse_still
from ...io.files.kalibr import kalibr_imu_yaml
from ...plots.allan import allan_plot_png
from ...errors import ConfigError, InputError
from ...io.sensors.clocks import check_same_clock
from ...io.messages.decode import IMU, LASERSCAN
from ...io.logs.detect import input_paths
from ...io.files.atomic import atomic_output, check_writable, make_folder
from ...io.files.output_paths import check_plot_dir, plot_outputs, refuse_shared_outputs
from ...io.logs.reader import open_log
from ...io.sensors.tf import read_static_frames
from ...io.sensors.topics import choose_topic
from ...core.calibration import AllanResult
from ...model.calibration import Calibration
from . import estimate as steps
from . import map as calibrate_map
from .clock import wheel_clock
from .ground import wheel_yaw
from .halves import halves_spread
from .plane_lever import lever_from_wheels
from .planar import ground_rotation
from .rest import rest_mounting
from .passes import (PLANAR_FUSION_SIGMAS, LidarPass, PassProgress, Progress, first_span_ns, pass_until,
                               read_imu, refine_spans, wheel_pass_config)
from .report import (T_lidar_imu_of, compose, imprecision_notes, reference_T_lidar_imu,
                               rotation_observable, table)
from ..odom.inputs import named_base, prefer_between, root_base
from ..outputs import sidecars, write_run

PLOT_NAME = "allan_deviation.png"
TAG = "calib"  # in the name of every file a run writes beside its YAML


@dataclass(frozen=True)
class CalibrateJob:
    """Everything one ``lio calibrate`` run needs. ``plot_dir``: write the Allan deviation plot there;
    ``kalibr``: also write Kalibr's imu.yaml (both need ``config.allan``)."""

    log: Path
    out: Path | None  # None: nothing is written (``-o -``: the CLI prints the YAML, ``yaml_text``)
    config: CalibrateConfig = field(default_factory=CalibrateConfig)
    plot_dir: Path | None = None
    kalibr: Path | None = None
    force: bool = False
    extra_inputs: tuple[Path, ...] = ()  # files read besides the log (--config, --calib): never outputs


@dataclass
class CalibrateResult:
    calibration: Calibration  # what the YAML holds
    table: list[dict]  # quantity, unit, value, sigma, diff (estimate - reference)
    reference: str | None  # what the differences are against
    skipped: list[steps.Skipped]
    config: CalibrateConfig  # resolved: repeats the run
    metrics: dict
    notes: list[str] = field(default_factory=list)
    outputs: list[Path] = field(default_factory=list)
    allan: AllanResult | None = None  # with ``config.allan``: for the Kalibr file and the plot


def check_calibrate_outputs(job: CalibrateJob) -> list[Path]:
    """Every output may be written and is none of the inputs (before any work); returns them."""
    if (job.plot_dir is not None or job.kalibr is not None) and not job.config.allan:
        raise ConfigError("--plot and --kalibr write the Allan variance results: give --allan too")
    inputs = [*input_paths(job.log), *job.extra_inputs]
    named = [] if job.out is None else [("the calibration (-o)", Path(job.out)),
                                        *zip(("its metrics", "its config"), sidecars(Path(job.out), TAG))]
    if job.kalibr is not None:
        named.append(("the Kalibr imu.yaml (--kalibr)", Path(job.kalibr)))
    refuse_shared_outputs([*named, *plot_outputs(job.plot_dir, (PLOT_NAME,))])  # -o x.yaml --kalibr x.yaml
    outs = [p for _, p in named]
    for p in outs:
        check_writable(p, job.force, inputs)
    if job.plot_dir is not None:
        check_plot_dir(Path(job.plot_dir), (PLOT_NAME,), job.force, inputs)
        outs.append(Path(job.plot_dir) / PLOT_NAME)
    return outs


def run_calibrate(job: CalibrateJob, progress: Progress | None = None) -> CalibrateResult:
    """Estimate the calibration of ``job.log`` (``write_calibrate`` writes it)."""
    t_wall = time.perf_counter()
    outs = check_calibrate_outputs(job)
    cfg, est, times = job.config, steps.Estimates(), {}
    with open_log(job.log, cfg.input.format) as reader:
        where = str(reader.path)
        if not any(i.msgtype == IMU and i.count > 0 for i in reader.topics.values()) and cfg.input.imu_topic is None:
            raise InputError(f"{where}: no IMU topic (sensor_msgs/Imu): lio calibrate calibrates an IMU (against the "
                             "LiDAR and the wheels); name one with --imu-topic")
        imu_topic = choose_topic(reader, "imu", cfg.input.imu_topic).topic
        lidar = choose_topic(reader, "lidar", cfg.input.lidar_topic, required=cfg.input.lidar_topic is not None).topic
        wheel = choose_topic(reader, "wheel", cfg.input.wheel_topic, required=cfg.input.wheel_topic is not None).topic \
            if lidar else None
        tree = read_static_frames(reader)
        base = named_base(tree, cfg.input.base_frame)  # None: the root of the sensors' tree (``root_base``)
        est.notes.extend(tree.warnings)
        still_s = None if cfg.still is None else parse_still(cfg.still)
        t0 = time.perf_counter()
        T_base_lidar = lidar_source = first_ns = None
        dropped = 0
        if lidar is None:
            imu = read_imu(reader, imu_topic)
            imu_frame, traj = imu.frame_id, None
            still_ns = _still_ns(imu, still_s)
            times["read"] = time.perf_counter() - t0
            steps.imu_at_rest(imu, still_ns, None if cfg.allan else "the log has no LiDAR: the IMU at rest is all "
                              "there is to calibrate", est, where)
            est.skip("lidar_imu", "the LiDAR-IMU time offset, rotation and translation", "the log has no LiDAR topic")
        else:
            check_same_clock(reader, lidar, imu_topic, cfg.start_offset_ns)
            planar = reader.topics[lidar].msgtype == LASERSCAN
            n = reader.topics[lidar].count
            spans = refine_spans(cfg.refine_passes, planar)
            counter = PassProgress(progress, n * (1 + len(spans)))  # until the passes' stretches are known
            topics = {"lidar": lidar, "imu": imu_topic, "wheel": wheel}
            first_ns = first_span_ns(len(spans), planar, reader.duration_ns)
            traj, arrays = LidarPass(reader, cfg, topics, planar, counter).run(gather=True, span_ns=first_ns)
            times["lidar_pass"] = time.perf_counter() - t0
            imu = arrays.imu
            if imu is None:
                raise InputError(f"{where}: {imu_topic}: no IMU sample could be read")
            imu_frame = arrays.imu_frame
            base = base or root_base(tree, arrays.lidar_frame or imu_frame, est.notes) or "base"
            still_ns = _still_ns(imu, still_s)
            T_base_lidar, lidar_source = _lidar_mounting(tree, base, arrays.lidar_frame, cfg.prior, est)
            ref, ref_name = _reference(cfg.prior, tree, base, imu_frame, T_base_lidar)
            T_ref = reference_T_lidar_imu(ref, T_base_lidar)
            prior_offset = cfg.imu_time_offset_s if cfg.imu_time_offset_s is not None else \
                cfg.prior.imu_time_offset_s if ref_name == "--calib" else None
            t0 = time.perf_counter()
            steps.imu_at_rest(imu, still_ns, None, est, where)
            bias0 = None if est.static is None else est.static.gyro_bias_radps
            wheel_clock(arrays, imu, cfg, est)
            # the refining passes' stretches are shares of the whole log, also when the first pass covered part
            s0, s1 = int(traj.stamps_ns[0]), max(int(traj.stamps_ns[-1]), arrays.last_scan_end_ns or 0)
            untils = [pass_until(span, s0, s1) for span in spans]
            counter.plan(sum(n if u is None else n * (u - s0) / max(s1 - s0, 1) for u in untils))
            while True:  # the first estimates; from all scans when the first part of the log cannot seed them
                traj, dropped = steps.consistent_scans(traj, imu, cfg.start_offset_s, bias0)
                try:
                    steps.extrinsics(traj, imu, cfg, est, where, T_ref, final=not spans, prior_offset=prior_offset)
                    break
                except InputError:
                    if first_ns is None:  # no mounting to prime a pass with: the LiDAR-only poses are final
                        steps.extrinsics(traj, imu, cfg, est, where, T_ref, final=True, prior_offset=prior_offset)
                        untils = []
                        est.notes.append("no gyro-primed pass: the motion did not turn the IMU enough to seed one; the "
                                         "LiDAR-only pass's poses are used throughout")
                        break
                est.notes.append(f"the LiDAR-only pass registered all of the log: its first {first_ns * 1e-9:.0f} s "
                                 "showed too little motion to seed the estimates")
                counter.plan(counter.total - counter.done + n)
                t_all = time.perf_counter()
                traj, _ = LidarPass(reader, cfg, {"lidar": lidar}, planar, counter).run()
                times["lidar_pass_all"] = time.perf_counter() - t_all
                first_ns = None
            times["estimate"] = time.perf_counter() - t0 - times.get("lidar_pass_all", 0.0)
            imu_topics = {"lidar": lidar, "imu": imu_topic}
            for k, until in enumerate(untils, start=1):
                t0 = time.perf_counter()
                fused = PLANAR_FUSION_SIGMAS[k - 1] if planar else None  # 2D scans: see PLANAR_FUSION_SIGMAS
                last = k == len(spans)
                mapped = last and calibrate_map.wanted(cfg, planar, n, est.notes)
                lp = LidarPass(reader, cfg, imu_topics, planar, counter)
                lp.sweep_voxel = calibrate_map.SWEEP_VOXEL if mapped else None
                traj, _ = lp.run(_mounting(est, T_ref), until_ns=until, fused_sigmas=fused)
                times[f"refine_pass_{k}"] = time.perf_counter() - t0
                if mapped:  # the final estimates, then the map rounds
                    traj, est = calibrate_map.map_rounds(traj, lp.sweeps, lp.voxel_m, imu, cfg, est, where, T_ref,
                                                         prior_offset, times)
                    continue
                t0 = time.perf_counter()
                try:
                    steps.extrinsics(traj, imu, cfg, est, where, T_ref, final=last, prior_offset=prior_offset)
                except InputError as err:
                    if last:
                        raise
                    # a partial pass whose stretch cannot time or turn the IMU leaves the estimates as they were
                    est.notes.append(f"refining pass {k} left the estimates as they were: {err}")
                times[f"estimate_{k}"] = time.perf_counter() - t0
            halves_spread(traj, imu, est)
            wheel_traj, against = traj, None
            if planar and untils and arrays.has_wheels and T_ref is None and est.rotation is not None and \
                    not rotation_observable(est).all():
                # a 2D scanner's IMU yaw unknown: its wheels are measured against a gyro-primed pass, which
                # de-skews through any yaw alike (a fused pass bends by a wrong yaw, a LiDAR-only one skews)
                t0 = time.perf_counter()
                counter.plan(n)
                wheel_traj, _ = LidarPass(reader, wheel_pass_config(cfg, lp.voxel_m), imu_topics, planar,
                                          counter).run(_mounting(est, T_ref))
                times["wheel_pass"] = time.perf_counter() - t0
                against = ("wheel scales measured against a gyro-primed pass (not fused with the IMU): the IMU's "
                           "mounting is not fully known (give T_base_imu with --calib, or /tf_static, to use the "
                           "fused one)")
            est.notes.extend(imprecision_notes(est, traj.T_world_lidar))
            steps.wheels(arrays, wheel_traj, T_base_lidar, cfg, est, where, against)
            rest_mounting(arrays, imu, T_base_lidar, T_ref, est)
            ground_rotation(arrays, imu, T_base_lidar, T_ref, est)
            wheel_yaw(arrays, imu, T_base_lidar, T_ref, est)
            lever_from_wheels(arrays, imu, T_base_lidar, T_ref, est)
            est.skip("T_base_lidar", "the LiDAR's mounting on the base (T_base_lidar)",
                     f"the motion shows the IMU against the LiDAR, not the LiDAR against the base: taken from {lidar_source}")
        if cfg.allan:
            t0 = time.perf_counter()
            steps.allan(imu, est, where)
            times["allan"] = time.perf_counter() - t0
        if lidar is None:
            base = base or root_base(tree, imu_frame, est.notes) or "base"
            ref, ref_name = _reference(cfg.prior, tree, base, imu_frame, None)
            T_ref = None
        fmt, span_s = reader.format, reader.duration_ns * 1e-9
    if not est.anything():
        raise InputError(f"{where}: nothing could be estimated: " + "; ".join(
            f"{s.item}: {s.reason}" for s in est.skipped if s.key != "T_base_lidar"))
    cal = compose(est, T_base_lidar, T_ref, wheel)
    rows = table(cal, ref, ref_name)
    resolved = with_overrides(cfg, {"input.lidar_topic": lidar, "input.imu_topic": imu_topic,
                                    "input.wheel_topic": wheel, "input.base_frame": base}, "resolved configuration")
    wall = time.perf_counter() - t_wall
    notes = list(dict.fromkeys(est.notes))
    metrics = {
        "command": "calibrate", "log": str(job.log), "format": fmt, "output": "-" if job.out is None else str(job.out),
        "topics": {"lidar": lidar, "imu": imu_topic, "wheel": wheel}, "base_frame": base,
        "T_base_lidar_from": lidar_source, "reference": ref_name,
        "lidar_trajectory": None if traj is None else traj.description,
        "lidar_only_pass": None if traj is None else "all scans" if first_ns is None else
        f"the scans of the first {first_ns * 1e-9:g} s",
        "lidar_only_scans_left_out": dropped,
        "conventions": {"T_base_imu": "maps IMU points into the base frame",
                        "imu_time_offset_s": "added to IMU stamps to put them on the LiDAR's clock"},
        "calibration": cal.model_dump(mode="json", exclude_none=True, exclude_unset=True), "table": rows,
        "not_estimated": not_estimated(est.skipped),
        "estimators": {k: v.to_dict() for k, v in (("imu_static", est.static), ("time_offset", est.offset),
                                                   ("rotation", est.rotation), ("lever_arm", est.lever),
                                                   ("wheel", est.wheel)) if v is not None},
        "allan": None if est.allan is None else _allan_summary(est.allan),
        "time_s": {**{k: round(v, 4) for k, v in times.items()}, "total": round(wall, 4)},
        "log_duration_s": round(span_s, 4), "notes": notes,
    }
    return CalibrateResult(cal, rows, ref_name, est.skipped, resolved, metrics, notes, outs, est.allan)


def not_estimated(skipped: list[steps.Skipped]) -> dict[str, str]:
    """{quantity: why} of what a run did not estimate (two reasons for one quantity joined)."""
    out: dict[str, str] = {}
    for s in skipped:
        out[s.key] = f"{out[s.key]}; {s.reason}" if s.key in out and s.reason not in out[s.key] else s.reason
    return out


def _mounting(est: steps.Estimates, T_ref) -> tuple[np.ndarray, float, np.ndarray]:
    """What a gyro-primed pass needs of the estimates so far: (T_lidar_imu, clock offset, gyro bias)."""
    return T_lidar_imu_of(est, T_ref), est.offset.imu_time_offset_s, est.rotation.gyro_bias_radps


def _still_ns(imu, still_s: tuple[float, float] | None) -> tuple[int, int] | None:
    """--still START:END (seconds after the first IMU sample) as IMU stamps."""
    if still_s is None:
        return None
    t0 = int(imu.stamps_ns[0])
    return t0 + int(round(still_s[0] * 1e9)), t0 + int(round(still_s[1] * 1e9))


def _lidar_mounting(tree, base: str, frame: str, prior: Calibration, est: steps.Estimates) -> tuple[np.ndarray, str]:
    T = tree.lookup(base, frame) if frame else None
    if T is not None:
        chain = f"{tree.source(base, frame)} ({base} -> {frame})"
        if prior.T_base_lidar is None:
            return T, chain
        return prefer_between("T_base_lidar", chain, T, prior, est.notes)
    if prior.T_base_lidar is not None:
        return prior.matrix("T_base_lidar"), "--calib"
    est.notes.append(f"no T_base_lidar ({base} -> {frame or '?'}) in /tf_static or --calib: the LiDAR is taken as the "
                     "base (identity), so T_base_imu is the IMU in the LiDAR frame")
    return np.eye(4), "identity (assumed)"


def _reference(prior: Calibration, tree, base: str, imu_frame: str,
               T_base_lidar: np.ndarray | None) -> tuple[Calibration | None, str | None]:
    """What the estimates are compared with: --calib when it was given, else what /tf_static says."""
    if prior.model_dump(exclude_none=True, exclude={"prefer_file"}) != \
            Calibration().model_dump(exclude_none=True, exclude={"prefer_file"}):
        return prior, "--calib"
    T = tree.lookup(base, imu_frame) if imu_frame else None
    if T is None:
        return None, None
    fields = {"T_base_imu": T.tolist()}
    if T_base_lidar is not None:
        fields["T_base_lidar"] = np.asarray(T_base_lidar).tolist()
    return Calibration.model_validate(fields), tree.source(base, imu_frame)


def _allan_summary(r) -> dict:
    keep = ("noise_density", "noise_density_sigma", "random_walk", "random_walk_sigma", "noise_density_mean",
            "random_walk_mean", "bias_instability", "white_slope", "random_walk_slope")
    return {"rate_hz": r.rate_hz, "duration_s": r.duration_s,
            **{s: {k: v for k, v in getattr(r, s).to_dict().items() if k in keep} for s in ("gyro", "accel")}}


def write_calibrate(result: CalibrateResult, out: Path | None, force: bool, kalibr: Path | None = None,
                    plot_dir: Path | None = None) -> list[Path]:
    """The calibration YAML ``out`` with its config and metrics beside it (``out`` None: none of them, e.g. for
    ``-o -``), and the job's ``kalibr`` file and Allan plot in ``plot_dir`` (both need ``config.allan``); returns
    the paths written, the YAML's first."""
    written: list[Path] = []
    if kalibr is not None:
        with atomic_output(kalibr, force) as tmp:
            tmp.write_text(kalibr_imu_yaml(result.allan, result.metrics["topics"]["imu"], result.allan.rate_hz))
        written.append(Path(kalibr))
    if plot_dir is not None:
        make_folder(Path(plot_dir))
        with atomic_output(Path(plot_dir) / PLOT_NAME, force) as tmp:
            tmp.write_bytes(allan_plot_png(result.allan, f"Allan deviation: {Path(result.metrics['log']).name}"))
        written.append(Path(plot_dir) / PLOT_NAME)
    if out is None:
        return written
    yaml = yaml_text(result.calibration, result.metrics["not_estimated"])
    return [*write_run(Path(out), TAG, yaml, result.config, result.metrics, force), *written]


def yaml_text(cal: Calibration, not_estimated: dict[str, str] | None = None) -> str:
    """The calibration YAML as written: its header comment, what was not estimated (``not_estimated``,
    {quantity: why}) named in comments, and the values estimated (only those: a field unset is left out)."""
    import textwrap

    import yaml

    head = ("# lio calibrate: T_base_imu / T_base_lidar map sensor points into the base frame (4x4, metres);\n"
            "# imu_time_offset_s is added to IMU stamps to put them on the LiDAR's clock; *_sigma_* are 1-sigma\n"
            "# (rotations about, translations along the base axes). Read by --calib of odom, deskew and fuse.\n")
    if not_estimated:
        head += "# Not estimated (the value, where one is written, is the prior's or an assumption):\n"
        for key, why in not_estimated.items():
            head += "\n".join(textwrap.wrap(f"{key}: {why}", 116, initial_indent="# - ",
                                             subsequent_indent="#   ")) + "\n"
    # prefer_file is the reader's choice (--prefer-calib), not a measured value
    fields = cal.model_dump(mode="json", exclude_none=True, exclude_unset=True, exclude={"prefer_file"})
    return head + yaml.safe_dump(fields, sort_keys=False, default_flow_style=None, width=120)
