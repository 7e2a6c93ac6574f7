"""``simulate()``: run a scenario's sensors over time and write the log, the TUM ground truth and the truth JSON.

Outputs for ``OUT`` (``x.bag``, ``x.mcap`` or a ROS 2 folder ``x``): the log itself, ``x.gt.tum`` (pose of
``base`` in ``world``) and ``x.truth.json`` (the true extrinsics, biases, clock offset, wheel errors).
Everything is written atomically; existing outputs are refused unless ``force``.
"""

from __future__ import annotations

import heapq
import json
import re
from collections.abc import Callable
from dataclasses import asdict, dataclass, field
from pathlib import Path

import numpy as np

from ..errors import ConfigError
from ..io.files import check_writable, write_text_atomic
from ..io.trajectory_files import format_tum
from ..io.writer import LogWriter
from .scenarios import SCENARIOS, Scenario, build_scenario
from .sensors import NS, ImuSpec, LaserSpec, LidarSpec, Scan, laser_scan, spin_scan, synthesize_imu, wheel_odometry

START_NS = 1_700_000_000 * NS
TIME_CONVENTIONS = ("velodyne", "ouster", "livox", "hesai")
FORMATS = ("ros1", "ros2", "ros2-mcap", "mcap")
GT_RATE_HZ = 100.0

TOPIC_POINTS, TOPIC_SCAN, TOPIC_IMU = "/points", "/scan", "/imu"
TOPIC_WHEEL, TOPIC_GT, TOPIC_TF_STATIC = "/wheel/odom", "/ground_truth", "/tf_static"


@dataclass
class SimulationOptions:
    """Everything a run depends on besides scenario, duration and seed. ``noise_scale`` multiplies every
    sensor noise, bias and walk (0: ideal sensors); ``wheel_errors`` False: exact radius/baseline, no slip."""

    beams: int | None = None
    columns: int | None = None
    imu_rate_hz: float = 200.0
    time_convention: str = "velodyne"
    header_stamp: str = "start"  # what a cloud's header stamp marks: the sweep's start or its end
    imu_time_offset_s: float = 0.0
    noise_scale: float = 1.0
    range_noise_m: float | None = None
    dropout: float | None = None
    max_range_m: float | None = None
    accel_noise_density: float | None = None
    gyro_noise_density: float | None = None
    wheel_errors: bool = True


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

    def to_dict(self) -> dict:
        d = asdict(self)
        for k in ("log_path", "gt_path", "truth_path"):
            d[k] = str(d[k])
        return d


def output_paths(out: Path) -> tuple[Path, Path]:
    """(x.gt.tum, x.truth.json) beside the log ``out`` (suffix .bag/.mcap dropped, folders kept)."""
    out = Path(out)
    stem = out.name[: -len(out.suffix)] if out.suffix in (".bag", ".mcap", ".db3") else out.name
    return out.with_name(f"{stem}.gt.tum"), out.with_name(f"{stem}.truth.json")


def format_for(out: Path, fmt: str | None) -> str:
    """The output format asked, or inferred from the suffix (.bag ros1, .mcap mcap, otherwise a ROS 2 folder)."""
    if fmt is not None:
        if fmt not in FORMATS:
            raise ConfigError(f"unknown output format '{fmt}' (choose from ros1, ros2, ros2-mcap, mcap)")
        return fmt
    return {".bag": "ros1", ".mcap": "mcap"}.get(Path(out).suffix, "ros2")


def _imu_spec(sc: Scenario, opts: SimulationOptions, rng: np.random.Generator) -> ImuSpec:
    k = opts.noise_scale
    spec = ImuSpec(rate_hz=opts.imu_rate_hz, time_offset_ns=int(round(opts.imu_time_offset_s * NS)))
    spec.accel_noise_density = (opts.accel_noise_density if opts.accel_noise_density is not None else spec.accel_noise_density) * k
    spec.gyro_noise_density = (opts.gyro_noise_density if opts.gyro_noise_density is not None else spec.gyro_noise_density) * k
    spec.accel_bias_walk *= k
    spec.gyro_bias_walk *= k
    # constant biases typical of a MEMS unit (a few hundredths of m/s^2, a few tenths of deg/s)
    spec.accel_bias0_mps2 = np.clip(rng.normal(0.0, 0.04, 3), -0.1, 0.1) * k
    spec.gyro_bias0_radps = np.clip(rng.normal(0.0, 0.003, 3), -0.01, 0.01) * k
    return spec


def _configure(sc: Scenario, opts: SimulationOptions, rng: np.random.Generator) -> None:
    lid = sc.lidar
    lid.range_noise_m = (opts.range_noise_m if opts.range_noise_m is not None else lid.range_noise_m) * opts.noise_scale
    lid.dropout = (opts.dropout if opts.dropout is not None else lid.dropout) * min(opts.noise_scale, 1.0)
    if opts.max_range_m is not None:
        lid.max_range_m = opts.max_range_m
    if sc.wheels is not None and opts.wheel_errors and opts.noise_scale > 0:
        w = sc.wheels
        w.radius_scale_left = float(1.0 + np.clip(rng.normal(0.0, 0.01), -0.02, 0.02))
        w.radius_scale_right = float(1.0 + np.clip(rng.normal(0.0, 0.01), -0.02, 0.02))
        w.baseline_scale = float(1.0 + np.clip(rng.normal(0.0, 0.03), -0.06, 0.06))
        w.slip_left, w.slip_right = 0.25, 0.10


def _cloud_array(scan: Scan, convention: str, header_ns: int) -> np.ndarray:
    """The PointCloud2 point layout of each convention; relative times are offsets from ``header_ns``."""
    n = len(scan.points)
    rel_ns = scan.stamps_ns - header_ns
    if convention == "velodyne":
        dt = np.dtype([("x", "<f4"), ("y", "<f4"), ("z", "<f4"), ("intensity", "<f4"), ("ring", "<u2"), ("time", "<f4")])
    elif convention == "ouster":
        dt = np.dtype([("x", "<f4"), ("y", "<f4"), ("z", "<f4"), ("intensity", "<f4"), ("t", "<u4"),
                       ("reflectivity", "<u2"), ("ring", "<u2")])
    elif convention == "livox":
        dt = np.dtype([("x", "<f4"), ("y", "<f4"), ("z", "<f4"), ("intensity", "<f4"), ("tag", "u1"), ("line", "u1"),
                       ("offset_time", "<u4")])
    else:  # hesai
        dt = np.dtype([("x", "<f4"), ("y", "<f4"), ("z", "<f4"), ("intensity", "<f4"), ("timestamp", "<f8"), ("ring", "<u2")])
    arr = np.zeros(n, dtype=dt)
    arr["x"], arr["y"], arr["z"] = scan.points[:, 0], scan.points[:, 1], scan.points[:, 2]
    arr["intensity"] = scan.intensity
    if convention == "velodyne":
        arr["ring"], arr["time"] = scan.ring, rel_ns * 1e-9
    elif convention == "ouster":
        arr["t"], arr["ring"], arr["reflectivity"] = rel_ns, scan.ring, scan.intensity.astype(np.uint16)
    elif convention == "livox":
        arr["line"], arr["offset_time"] = scan.ring.astype(np.uint8), rel_ns
    else:
        arr["ring"] = scan.ring
        arr["timestamp"] = scan.stamps_ns // NS + (scan.stamps_ns % NS) * 1e-9
    return arr


def _truth(sc: Scenario, opts: SimulationOptions, imu, imu_spec: ImuSpec, seed: int, fmt: str, start_ns: int,
           end_ns: int) -> dict:
    lid = sc.lidar
    w = sc.wheels
    lidar = {"topic": TOPIC_POINTS if isinstance(lid, LidarSpec) else TOPIC_SCAN, "frame_id": "lidar",
             "period_s": lid.period_ns * 1e-9, "range_noise_m": lid.range_noise_m, "dropout": lid.dropout,
             "max_range_m": lid.max_range_m, "min_range_m": lid.min_range_m,
             "header_stamp_marks": opts.header_stamp if isinstance(lid, LidarSpec) else "start",
             "record_time": "scan end"}
    if isinstance(lid, LidarSpec):
        from .sensors import beam_elevations_deg

        lidar.update(type="spinning", beams=lid.beams, columns=lid.columns, time_convention=opts.time_convention,
                     elevations_deg=np.round(beam_elevations_deg(lid.beams), 6).tolist())
    else:
        lidar.update(type="planar", beams=lid.beams, angle_min_rad=lid.angle_min_rad,
                     angle_increment_rad=lid.angle_increment_rad)
    wheel = None
    if w is not None:
        slip = None
        if w.slip_start_s is not None and w.slip_duration_s > 0 and (w.slip_left or w.slip_right):
            slip = {"start_s": w.slip_start_s, "duration_s": w.slip_duration_s,
                    "start_ns": start_ns + int(round(w.slip_start_s * NS)),
                    "end_ns": start_ns + int(round((w.slip_start_s + w.slip_duration_s) * NS)),
                    "left": w.slip_left, "right": w.slip_right,
                    "meaning": "measured wheel speed = ground speed * (1 + slip) inside the window (raised-cosine edges)"}
        wheel = {"topic": TOPIC_WHEEL, "rate_hz": w.rate_hz, "radius_m_nominal": w.radius_m,
                 "baseline_m_nominal": w.baseline_m, "radius_scale_left": w.radius_scale_left,
                 "radius_scale_right": w.radius_scale_right, "baseline_scale": w.baseline_scale,
                 "scale_meaning": "true = nominal * scale; odometry uses the nominal values", "slip": slip}
    return {
        "scenario": sc.name, "description": sc.description, "seed": seed, "format": fmt,
        "start_ns": start_ns, "end_ns": end_ns, "duration_s": round((end_ns - start_ns) * 1e-9, 9),
        "gravity_mps2": [0.0, 0.0, -9.81],
        "frames": {"world": "fixed, z up; ground truth is T_world_base", "base": "x forward, y left, z up",
                   "odom": "wheel odometry origin = base pose at start"},
        "T_base_imu": (np.round(sc.T_base_imu, 12) + 0.0).tolist(), "T_base_lidar": (np.round(sc.T_base_lidar, 12) + 0.0).tolist(),
        "imu": {
            "topic": TOPIC_IMU, "frame_id": "imu", "rate_hz": imu_spec.rate_hz,
            "time_offset_s": imu_spec.time_offset_ns * 1e-9, "time_offset_ns": imu_spec.time_offset_ns,
            "time_offset_meaning": "imu stamp = true sampling time + offset (LiDAR and ground truth carry true time)",
            "accel_bias_mps2": imu.accel_bias_mps2[0].tolist(), "gyro_bias_radps": imu.gyro_bias_radps[0].tolist(),
            "accel_bias_final_mps2": imu.accel_bias_mps2[-1].tolist(), "gyro_bias_final_radps": imu.gyro_bias_radps[-1].tolist(),
            "accel_bias_mean_mps2": imu.accel_bias_mps2.mean(axis=0).tolist(),
            "gyro_bias_mean_radps": imu.gyro_bias_radps.mean(axis=0).tolist(),
            "accel_noise_density": imu_spec.accel_noise_density, "gyro_noise_density": imu_spec.gyro_noise_density,
            "accel_bias_walk": imu_spec.accel_bias_walk, "gyro_bias_walk": imu_spec.gyro_bias_walk,
        },
        "lidar": lidar, "wheel": wheel,
        "ground_truth": {"topic": TOPIC_GT, "frame_id": "world", "child": "base", "rate_hz": GT_RATE_HZ},
        "noise_scale": opts.noise_scale, "rest_s": sc.trajectory.t_rest_s,
    }


def simulate(scenario: str, out: str | Path, fmt: str | None = None, duration_s: float = 20.0, seed: int = 0,
             force: bool = False, progress: Callable[[float], None] | None = None, **options) -> SimulationResult:
    """Simulate ``scenario`` for ``duration_s`` and write the log ``out`` plus ``x.gt.tum`` and ``x.truth.json``.

    ``options`` are :class:`SimulationOptions` fields. ``progress(dt_s)`` is called as simulated time advances.
    The same arguments always give the same bytes.
    """
    if scenario not in SCENARIOS:
        raise ConfigError(f"unknown scenario '{scenario}' (choose from {', '.join(SCENARIOS)})")
    unknown = set(options) - set(SimulationOptions.__dataclass_fields__)
    if unknown:
        raise ConfigError(f"unknown simulation option(s): {', '.join(sorted(unknown))}")
    opts = SimulationOptions(**options)
    _validate(opts, duration_s)
    out = Path(out)
    fmt = format_for(out, fmt)
    gt_path, truth_path = output_paths(out)
    for p in (out, gt_path, truth_path):
        check_writable(p, force)

    sc = build_scenario(scenario, opts.beams, opts.columns)
    root = np.random.SeedSequence(seed)
    rng_cfg, rng_imu, rng_lidar = (np.random.default_rng(s) for s in root.spawn(3))
    _configure(sc, opts, rng_cfg)
    if sc.wheels is not None:
        sc.wheels.slip_start_s = sc.trajectory.t_rest_s + 0.45 * max(duration_s - sc.trajectory.t_rest_s, 0.0)
        sc.wheels.slip_duration_s = min(1.0, 0.2 * duration_s) if opts.wheel_errors and opts.noise_scale > 0 else 0.0
    imu_spec = _imu_spec(sc, opts, rng_imu)
    noisy = opts.noise_scale > 0
    start_ns = START_NS
    end_ns = start_ns + int(round(duration_s * NS))
    period = sc.lidar.period_ns
    n_scans = (end_ns - start_ns) // period

    imu = synthesize_imu(sc.trajectory, sc.T_base_imu, imu_spec, start_ns, end_ns, start_ns, rng_imu if noisy else None)
    gt_step = int(round(NS / GT_RATE_HZ))
    gt_ns = np.arange(start_ns, end_ns + 1, gt_step, dtype=np.int64)
    gt_poses = sc.trajectory.poses((gt_ns - start_ns) * 1e-9)
    wheel = wheel_odometry(sc.trajectory, sc.wheels, start_ns, end_ns, start_ns) if sc.wheels is not None else None

    spinning = isinstance(sc.lidar, LidarSpec)
    lidar_topic = TOPIC_POINTS if spinning else TOPIC_SCAN
    counts: dict[str, int] = {}
    with LogWriter(out, fmt, force=force) as wr:
        mk = wr.make
        types = {TOPIC_TF_STATIC: "tf2_msgs/msg/TFMessage", TOPIC_IMU: "sensor_msgs/msg/Imu",
                 TOPIC_GT: "geometry_msgs/msg/PoseStamped",
                 lidar_topic: "sensor_msgs/msg/PointCloud2" if spinning else "sensor_msgs/msg/LaserScan"}
        if wheel is not None:
            types[TOPIC_WHEEL] = "nav_msgs/msg/Odometry"
        wr.add_topic(TOPIC_TF_STATIC, types[TOPIC_TF_STATIC], latching=True)
        for topic in (lidar_topic, TOPIC_IMU, TOPIC_WHEEL, TOPIC_GT):
            if topic in types:
                wr.add_topic(topic, types[topic])

        def put(topic: str, t_ns: int, msg) -> None:
            wr.write(topic, int(t_ns), msg)
            counts[topic] = counts.get(topic, 0) + 1

        first_ns = min(start_ns, int(imu.stamps_ns[0]))
        put(TOPIC_TF_STATIC, first_ns, mk.tf_message([
            mk.transform_stamped(first_ns, "base", "imu", sc.T_base_imu),
            mk.transform_stamped(first_ns, "base", "lidar", sc.T_base_lidar),
        ]))
        # small time-ordered streams, merged with the scans window by window
        streams = [((int(s), 1, TOPIC_IMU, i) for i, s in enumerate(imu.stamps_ns)),
                   ((int(s), 3, TOPIC_GT, i) for i, s in enumerate(gt_ns))]
        if wheel is not None:
            streams.append(((int(s), 2, TOPIC_WHEEL, i) for i, s in enumerate(wheel.stamps_ns)))
        events = heapq.merge(*streams)
        pending = next(events, None)

        def flush(until_ns: int) -> None:
            nonlocal pending
            while pending is not None and pending[0] <= until_ns:
                t, _, topic, i = pending
                if topic == TOPIC_IMU:
                    put(topic, t, mk.imu(t, "imu", imu.gyro_radps[i], imu.accel_mps2[i]))
                elif topic == TOPIC_GT:
                    put(topic, t, mk.pose_stamped(t, "world", gt_poses[i]))
                else:
                    put(topic, t, mk.odometry(t, "odom", "base", wheel.poses_odom_base[i],
                                              (wheel.linear_mps[i], 0.0, 0.0), (0.0, 0.0, wheel.angular_radps[i])))
                pending = next(events, None)

        for k in range(n_scans):
            scan_start = start_ns + k * period
            scan_end = scan_start + period
            flush(scan_end)
            if spinning:
                scan = spin_scan(sc.world, sc.trajectory, sc.T_base_lidar, sc.lidar, scan_start, start_ns,
                                 rng_lidar if noisy else None)
                header_ns = scan_start if opts.header_stamp == "start" else scan_end
                put(lidar_topic, scan_end,
                    mk.pointcloud2(header_ns, "lidar", _cloud_array(scan, opts.time_convention, header_ns)))
            else:
                lspec: LaserSpec = sc.lidar
                ranges = laser_scan(sc.world, sc.trajectory, sc.T_base_lidar, lspec, scan_start, start_ns,
                                    rng_lidar if noisy else None)
                put(lidar_topic, scan_end, mk.laserscan(scan_start, "lidar", lspec.angle_min_rad,
                                                        lspec.angle_increment_rad, lspec.time_increment_s,
                                                        lspec.period_ns * 1e-9, lspec.min_range_m, lspec.max_range_m,
                                                        ranges))
            if progress is not None:
                progress(period * 1e-9)
        flush(end_ns + NS)

    write_text_atomic(gt_path, format_tum(gt_ns, gt_poses), force=force)
    truth = _truth(sc, opts, imu, imu_spec, seed, fmt, start_ns, end_ns)
    write_text_atomic(truth_path, compact_json(truth), force=force)

    rates = {TOPIC_IMU: imu_spec.rate_hz, TOPIC_GT: GT_RATE_HZ, lidar_topic: NS / period,
             TOPIC_WHEEL: sc.wheels.rate_hz if sc.wheels else None, TOPIC_TF_STATIC: None}
    topics = {t: {"type": types[t], "count": counts.get(t, 0), "rate_hz": rates[t]} for t in types}
    size = sum(f.stat().st_size for f in out.rglob("*")) if out.is_dir() else out.stat().st_size
    return SimulationResult(scenario, fmt, seed, duration_s, out, gt_path, truth_path, start_ns, end_ns, topics,
                            int(size + gt_path.stat().st_size + truth_path.stat().st_size))


def compact_json(obj) -> str:
    """Indented JSON with innermost lists (vectors, matrix rows) kept on one line."""
    text = json.dumps(obj, indent=2)
    return re.sub(r"\[\n\s+([^\[\]{}]*?)\n\s*\]", lambda m: "[" + " ".join(m.group(1).split()) + "]", text) + "\n"


def _validate(opts: SimulationOptions, duration_s: float) -> None:
    if not (duration_s > 0 and np.isfinite(duration_s)):
        raise ConfigError(f"--duration must be positive (got {duration_s})")
    if duration_s > 3600:
        raise ConfigError(f"--duration {duration_s} s is more than an hour; simulate shorter pieces")
    if opts.time_convention not in TIME_CONVENTIONS:
        raise ConfigError(f"unknown --time-convention '{opts.time_convention}' (choose from {', '.join(TIME_CONVENTIONS)})")
    if opts.header_stamp not in ("start", "end"):
        raise ConfigError(f"--header-stamp must be start or end (got '{opts.header_stamp}')")
    if opts.header_stamp == "end" and opts.time_convention in ("ouster", "livox"):
        raise ConfigError(f"--header-stamp end needs negative per-point offsets, which the {opts.time_convention} "
                          "convention (unsigned ns) cannot hold; use --time-convention velodyne or hesai")
    if opts.beams is not None and opts.beams not in (16, 32, 64, 128):
        raise ConfigError(f"--beams must be 16, 32, 64 or 128 (got {opts.beams})")
    if opts.columns is not None and not 16 <= opts.columns <= 4096:
        raise ConfigError(f"--columns must be between 16 and 4096 (got {opts.columns})")
    if not 10.0 <= opts.imu_rate_hz <= 2000.0:
        raise ConfigError(f"--imu-rate must be between 10 and 2000 Hz (got {opts.imu_rate_hz})")
    if opts.noise_scale < 0:
        raise ConfigError(f"--noise-scale must be >= 0 (got {opts.noise_scale})")
    if abs(opts.imu_time_offset_s) > 0.5:
        raise ConfigError(f"--imu-time-offset must be within +-0.5 s (got {opts.imu_time_offset_s})")
    if opts.range_noise_m is not None and not opts.range_noise_m >= 0.0:
        raise ConfigError(f"--range-noise must be >= 0 m (got {opts.range_noise_m})")
    if opts.max_range_m is not None and not 1.0 <= opts.max_range_m <= 1000.0:
        raise ConfigError(f"--max-range must be between 1 and 1000 m (got {opts.max_range_m})")
    for flag, value in (("--accel-noise", opts.accel_noise_density), ("--gyro-noise", opts.gyro_noise_density)):
        if value is not None and not value >= 0.0:
            raise ConfigError(f"{flag} must be >= 0 (got {value})")
    if opts.dropout is not None and not 0.0 <= opts.dropout < 1.0:
        raise ConfigError(f"--dropout must be in [0, 1) (got {opts.dropout})")
