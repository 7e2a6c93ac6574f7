"""``simulate()``: run a scenario's sensors over time and write the log, the TUM ground truth, the truth JSON
and the run's metrics.

Outputs for ``OUT`` (``x.bag``, ``x.mcap`` or a ROS 2 folder ``x``): the log itself, ``x.gt.tum`` (pose of
``base`` in ``world``), ``x.truth.json`` (the true extrinsics, biases, clock offset, wheel errors, start state,
GPS georeference) and ``x.sim.metrics.json`` (the resolved options, topics, sizes, wall time). Everything is
written atomically; existing outputs are refused unless ``force``.
"""

from __future__ import annotations

import json
import re
import time
from collections.abc import Callable
from dataclasses import asdict, dataclass, field
from pathlib import Path

import numpy as np

from .. import __version__
from ..errors import ConfigError
from ..geometry import make_pose
from ..io.files.atomic import check_writable, write_text_atomic
from ..io.logs.writer import SUFFIX_FORMATS
from ..io.files.trajectory import format_tum
from .gps import MODEL_DEFAULTS, GpsSpec, gps_fixes
from .motion import ypr_to_matrix
from .options import TIME_CONVENTIONS, SimulationOptions, validate
from .record import TOPIC_GPS, TOPIC_IMU, TOPIC_TF_STATIC, TOPIC_WHEEL, Streams, gt_type_of, write_sensor_log
from .scenarios import ALL_SCENARIOS, Scenario, build_scenario
from .sensors import NS, ImuSpec, LidarSpec, slip_bursts, synthesize_imu, wheel_odometry
from .static import STATIC_GT_RATE_HZ, write_static_log
from .truth import RunFacts, bias_stats, truth_dict

__all__ = ["FORMATS", "TIME_CONVENTIONS", "SimulationOptions", "SimulationResult", "output_paths", "simulate"]

START_NS = 1_700_000_000 * NS
FORMATS = ("ros1", "ros2", "ros2-mcap", "mcap")
GT_RATE_HZ = 100.0


@dataclass
class SimulationResult:
    scenario: str
    format: str
    seed: int
    duration_s: float
    log_path: Path
    gt_path: Path
    truth_path: Path
    start_ns: int
    end_ns: int
    topics: dict[str, dict] = field(default_factory=dict)  # topic -> {type, count, rate_hz}
    bytes_written: int = 0
    metrics_path: Path | None = None

    def to_dict(self) -> dict:
        d = asdict(self)
        for k in ("log_path", "gt_path", "truth_path", "metrics_path"):
            d[k] = None if d[k] is None else str(d[k])
        return d


def output_paths(out: Path) -> tuple[Path, Path]:
    """(x.gt.tum, x.truth.json) beside the log ``out`` (suffix .bag/.mcap dropped, folders kept)."""
    out = Path(out)
    stem = _stem(out)
    return out.with_name(f"{stem}.gt.tum"), out.with_name(f"{stem}.truth.json")


def metrics_path_for(out: Path) -> Path:
    """x.sim.metrics.json beside the log ``out`` (tagged, as every command's side files: never another's)."""
    out = Path(out)
    return out.with_name(f"{_stem(out)}.sim.metrics.json")


def _stem(out: Path) -> str:
    return out.name[: -len(out.suffix)] if out.suffix in (".bag", ".mcap", ".db3") else out.name


def format_for(out: Path, fmt: str | None) -> str:
    """The output format asked, or inferred from the suffix (.bag ros1, .mcap mcap, otherwise a ROS 2 folder)."""
    if fmt is not None:
        if fmt not in FORMATS:
            raise ConfigError(f"unknown output format '{fmt}' (choose from ros1, ros2, ros2-mcap, mcap)")
        return fmt
    return SUFFIX_FORMATS.get(Path(out).suffix, "ros2")


def _imu_spec(sc: Scenario, opts: SimulationOptions, rng: np.random.Generator) -> ImuSpec:
    k = opts.noise_scale
    spec = ImuSpec(rate_hz=opts.imu_rate_hz, imu_time_offset_ns=int(round(opts.imu_time_offset_s * NS)))
    spec.accel_noise_density = (opts.accel_noise_density if opts.accel_noise_density is not None else spec.accel_noise_density) * k
    spec.gyro_noise_density = (opts.gyro_noise_density if opts.gyro_noise_density is not None else spec.gyro_noise_density) * k
    spec.accel_bias_walk = (opts.accel_bias_walk if opts.accel_bias_walk is not None else spec.accel_bias_walk) * k
    spec.gyro_bias_walk = (opts.gyro_bias_walk if opts.gyro_bias_walk is not None else spec.gyro_bias_walk) * k
    # constant biases typical of a MEMS unit (a few hundredths of m/s^2, a few tenths of deg/s)
    spec.accel_bias0_mps2 = np.clip(rng.normal(0.0, 0.04, 3), -0.1, 0.1) * k
    spec.gyro_bias0_radps = np.clip(rng.normal(0.0, 0.003, 3), -0.01, 0.01) * k
    if opts.accel_bias_mps2 is not None:  # given explicitly: as is, not scaled
        spec.accel_bias0_mps2 = np.asarray(opts.accel_bias_mps2, float)
    if opts.gyro_bias_radps is not None:
        spec.gyro_bias0_radps = np.asarray(opts.gyro_bias_radps, float)
    return spec


def _configure(sc: Scenario, opts: SimulationOptions, rng: np.random.Generator) -> None:
    lid = sc.lidar
    if lid is not None:
        lid.range_noise_m = (opts.range_noise_m if opts.range_noise_m is not None else lid.range_noise_m) * opts.noise_scale
        lid.dropout = (opts.dropout if opts.dropout is not None else lid.dropout) * min(opts.noise_scale, 1.0)
        if opts.max_range_m is not None:
            lid.max_range_m = opts.max_range_m
    w = sc.wheels
    if w is None:
        return
    if opts.wheel_errors and opts.noise_scale > 0:
        w.radius_scale_left = float(1.0 + np.clip(rng.normal(0.0, 0.01), -0.02, 0.02))
        w.radius_scale_right = float(1.0 + np.clip(rng.normal(0.0, 0.01), -0.02, 0.02))
        w.baseline_scale = float(1.0 + np.clip(rng.normal(0.0, 0.03), -0.06, 0.06))
        w.slip_left, w.slip_right = 0.25, 0.10
    if opts.wheel_radius_scale is not None:  # given explicitly: applies whatever --wheel-errors says
        w.radius_scale_left, w.radius_scale_right = (float(v) for v in opts.wheel_radius_scale)
    if opts.wheel_baseline_scale is not None:
        w.baseline_scale = float(opts.wheel_baseline_scale)


def _mount_imu(sc: Scenario, opts: SimulationOptions) -> None:
    """Apply ``--imu-rotation`` / ``--imu-lever-arm`` to the scenario's T_base_imu."""
    if opts.imu_rotation_deg is None and opts.imu_lever_arm_m is None:
        return
    R, t = sc.T_base_imu[:3, :3], sc.T_base_imu[:3, 3]
    if opts.imu_rotation_deg is not None:
        roll, pitch, yaw = np.radians(opts.imu_rotation_deg)
        R = ypr_to_matrix(np.array(yaw), np.array(pitch), np.array(roll))
    if opts.imu_lever_arm_m is not None:
        t = np.asarray(opts.imu_lever_arm_m, float)
    sc.T_base_imu = make_pose(R, t)


def _gps_spec(sc: Scenario, opts: SimulationOptions, duration_s: float) -> GpsSpec:
    outage = min(10.0, 0.1 * duration_s) if opts.gps_outage_s is None else opts.gps_outage_s
    noise, share, tau, wander, jump, cov = MODEL_DEFAULTS[opts.gps_model]
    noise = noise if opts.gps_noise_m is None else opts.gps_noise_m
    wander = wander if opts.gps_alt_wander_m is None else opts.gps_alt_wander_m
    jump = jump if opts.gps_jump_m is None else opts.gps_jump_m
    k = opts.noise_scale
    return GpsSpec(rate_hz=opts.gps_rate_hz, origin=tuple(opts.gps_origin), noise_m=tuple(v * k for v in noise),
                   correlated_share=share, tau_s=tau, invalid_fraction=opts.gps_invalid_fraction,
                   outage_start_s=0.55 * duration_s, outage_s=outage, antenna_m=sc.gps_antenna_m,
                   model=opts.gps_model, alt_wander_m=wander * k, jump_m=jump * k, jump_start_s=0.3 * duration_s,
                   jump_s=min(5.0, 0.1 * duration_s), covariance=opts.gps_covariance or cov)


def simulate(scenario: str, out: str | Path, fmt: str | None = None, duration_s: float = 20.0, seed: int = 0,
             force: bool = False, progress: Callable[[float], None] | None = None, **options) -> SimulationResult:
    """Simulate ``scenario`` for ``duration_s`` and write the log ``out`` plus ``x.gt.tum``, ``x.truth.json`` and
    ``x.sim.metrics.json``.

    ``options`` are :class:`SimulationOptions` fields. ``progress(dt_s)`` is called as simulated time advances.
    The same arguments always give the same bytes (the metrics' wall time aside).
    """
    t_wall = time.perf_counter()
    if scenario not in ALL_SCENARIOS:
        raise ConfigError(f"unknown scenario '{scenario}' (choose from {', '.join(ALL_SCENARIOS)})")
    unknown = set(options) - set(SimulationOptions.__dataclass_fields__)
    if unknown:
        raise ConfigError(f"unknown simulation option(s): {', '.join(sorted(unknown))}")
    opts = SimulationOptions(**options)
    validate(opts, scenario, duration_s)
    out = Path(out)
    fmt = format_for(out, fmt)
    gt_path, truth_path = output_paths(out)
    metrics_path = metrics_path_for(out)
    for p in (out, gt_path, truth_path, metrics_path):
        check_writable(p, force)

    sc = build_scenario(scenario, opts.beams, opts.columns, opts.start, opts.tilt_scale, opts.stops, opts.hills)
    _mount_imu(sc, opts)
    if opts.wheel is False:
        sc.wheels = None
    root = np.random.SeedSequence(seed)
    rng_cfg, rng_imu, rng_lidar = (np.random.default_rng(s) for s in root.spawn(3))
    _configure(sc, opts, rng_cfg)
    if sc.wheels is not None:
        sc.wheels.slip_start_s = sc.rest_s + 0.45 * max(duration_s - sc.rest_s, 0.0)
        sc.wheels.slip_duration_s = min(1.0, 0.2 * duration_s) if opts.wheel_errors and opts.noise_scale > 0 else 0.0
        if opts.wheel_slip_bursts:  # their own stream: every other draw stays as without them
            rng_slip = np.random.default_rng(np.random.SeedSequence(seed, spawn_key=(101,)))
            sc.wheels.bursts = slip_bursts(opts.wheel_slip_bursts, sc.rest_s, duration_s, rng_slip)
    imu_spec = _imu_spec(sc, opts, rng_imu)
    noisy = opts.noise_scale > 0
    start_ns = START_NS
    end_ns = start_ns + int(round(duration_s * NS))
    gt_type = gt_type_of(sc, opts)
    gt_rate = STATIC_GT_RATE_HZ if sc.lidar is None else GT_RATE_HZ
    gt_ns = np.arange(start_ns, end_ns + 1, int(round(NS / gt_rate)), dtype=np.int64)
    gt_state = sc.trajectory.state((gt_ns - start_ns) * 1e-9)
    initial = sc.trajectory.state(np.array([0.0]))

    if sc.lidar is None:
        types, counts, summary = write_static_log(out, fmt, force, sc, opts, imu_spec, start_ns, end_ns, gt_ns,
                                                  gt_state, rng_imu if noisy else None, progress)
        facts = RunFacts(gt_type, gt_rate, start_ns, None, initial)
        bias = summary.as_dict()
        lidar_topic = None
    else:
        delay_ns = int(round(opts.imu_start_delay_s * NS))
        imu = synthesize_imu(sc.trajectory, sc.T_base_imu, imu_spec, start_ns + delay_ns, end_ns, start_ns,
                             rng_imu if noisy else None)
        wheel = wheel_odometry(sc.trajectory, sc.wheels, start_ns, end_ns, start_ns) if sc.wheels is not None else None
        gps = None
        if opts.gps:
            gspec = _gps_spec(sc, opts, duration_s)
            gps = (gspec, gps_fixes(sc.trajectory, gspec, start_ns, end_ns, start_ns, np.random.default_rng(root.spawn(1)[0])))
        data = Streams(imu, gt_ns, gt_state, wheel, None if gps is None else gps[1])
        types, counts = write_sensor_log(out, fmt, force, sc, opts, data, start_ns, end_ns,
                                         rng_lidar if noisy else None, progress)
        spinning = isinstance(sc.lidar, LidarSpec)
        header_ns = start_ns + (sc.lidar.period_ns if spinning and opts.header_stamp == "end" else 0)
        facts = RunFacts(gt_type, gt_rate, int(imu.stamps_ns[0]), header_ns, initial, gps)
        bias = bias_stats(imu)
        lidar_topic = None if not opts.lidar else "/points" if spinning else "/scan"

    write_text_atomic(gt_path, format_tum(gt_ns, gt_state.poses), force=force)
    truth = truth_dict(sc, opts, imu_spec, bias, seed, fmt, start_ns, end_ns, facts)
    write_text_atomic(truth_path, compact_json(truth), force=force)

    rates = {TOPIC_IMU: imu_spec.rate_hz, opts.gt_topic: gt_rate, TOPIC_WHEEL: sc.wheels.rate_hz if sc.wheels else None,
             TOPIC_TF_STATIC: None, TOPIC_GPS: opts.gps_rate_hz if opts.gps else None}
    if lidar_topic is not None:
        rates[lidar_topic] = NS / sc.lidar.period_ns
    topics = {t: {"type": types[t], "count": counts.get(t, 0), "rate_hz": rates[t]} for t in types}
    size = sum(f.stat().st_size for f in out.rglob("*")) if out.is_dir() else out.stat().st_size
    res = SimulationResult(scenario, fmt, seed, duration_s, out, gt_path, truth_path, start_ns, end_ns, topics,
                           int(size + gt_path.stat().st_size + truth_path.stat().st_size), metrics_path)
    wall = time.perf_counter() - t_wall
    metrics = {"command": "simulate", "lio_version": __version__, "scenario": scenario, "format": fmt, "seed": seed,
               "duration_s": duration_s, "options": opts.to_dict(),
               "outputs": {"log": str(out), "ground_truth": str(gt_path), "truth": str(truth_path)},
               "topics": topics, "bytes_written": res.bytes_written, "wall_s": round(wall, 3),
               "realtime_factor": round(duration_s / wall, 3) if wall > 0 else None}
    write_text_atomic(metrics_path, compact_json(metrics), force=force)
    return res


def compact_json(obj) -> str:
    """Indented JSON with innermost lists (vectors, matrix rows) kept on one line."""
    text = json.dumps(obj, indent=2)
    return re.sub(r"\[\n\s+([^\[\]{}]*?)\n\s*\]", lambda m: "[" + " ".join(m.group(1).split()) + "]", text) + "\n"
