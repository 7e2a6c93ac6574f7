"""The ``odom`` job: read a log's stream, resolve topics and extrinsics, drive ``LioOdometry``, gather metrics.

``OdomJob`` (log + the whole configuration + optional ground truth) is all a run needs; ``run_odom`` returns
the trajectory, the resolved configuration (topics, base frame and deskew filled in: written beside the
outputs, it repeats the run exactly), metrics and notes.
"""

from __future__ import annotations

import time
from collections import deque
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from ..config import with_overrides
from ..config.odom import OdomConfig
from ..core.odometry import LioOdometry, OdomStats
from ..errors import InputError
from ..evaluation.scoring import Score, score
from ..io.decode import LASERSCAN
from ..io.pointcloud import parse_time_convention
from ..io.reader import LogReader, open_log
from ..io.sources import load_trajectory
from ..io.stream import SensorStream
from ..io.tf import FrameTree, read_static_frames
from ..io.topics import select_topic
from ..model.calibration import Calibration, Extrinsics
from ..model.records import ImuBatch, PointCloud
from ..model.trajectory import Trajectory

BASE_FRAME_NAMES = ("base_link", "base", "base_footprint")
_IMU_WAIT_NS = 500_000_000  # a scan waits at most this long (log time) for IMU covering its end

Progress = Callable[[int, int | None], None]  # (scans done, scans in the log or None)


@dataclass(frozen=True)
class OdomJob:
    """Everything one ``lio odom`` run needs. ``gt``: a TUM/KITTI file or a topic of the log to score against."""

    log: Path
    config: OdomConfig = field(default_factory=OdomConfig)
    gt: str | None = None


@dataclass
class OdomResult:
    trajectory: Trajectory  # poses of the output frame at the instants the scans were de-skewed to
    config: OdomConfig  # resolved: repeats the run
    stats: OdomStats
    initialisation: str | None
    metrics: dict
    notes: list[str] = field(default_factory=list)
    score: Score | None = None


def resolve_extrinsics(tree: FrameTree, calib: Calibration, base_frame: str | None, imu_frame: str | None,
                       lidar_frame: str, notes: list[str]) -> tuple[Extrinsics, dict]:
    """T_base_imu and T_base_lidar from /tf_static by frame_id, else the calibration, else identity (noted).

    ``imu_frame`` None: the IMU is not used, so its extrinsic is not looked for.
    """
    base = base_frame or next((b for b in BASE_FRAME_NAMES if b in tree.frames), "base")
    found, source = {"T_base_imu": np.eye(4)}, {"T_base_imu": "not used (no IMU in this run)"}
    wanted = [("T_base_lidar", lidar_frame)] if imu_frame is None else [("T_base_imu", imu_frame), ("T_base_lidar", lidar_frame)]
    for name, frame in wanted:
        T = tree.lookup(base, frame) if frame else None
        if T is not None:
            found[name], source[name] = T, f"/tf_static ({base} -> {frame})"
        elif calib.matrix(name) is not None:
            found[name], source[name] = calib.matrix(name), "--calib"
        else:
            found[name], source[name] = np.eye(4), "identity (assumed)"
            notes.append(f"no extrinsic {name} ({base} -> {frame or '?'}) in /tf_static or --calib: identity assumed")
    return Extrinsics(found["T_base_imu"], found["T_base_lidar"]), {"base_frame": base, **source}


def run_odom(job: OdomJob, progress: Progress | None = None) -> OdomResult:
    """Run odometry over ``job.log``; score against ``job.gt`` when given."""
    with open_log(job.log, job.config.input.format) as reader:
        result = _run(reader, job.config, progress)
    if job.gt is not None:
        spec = f"{job.log}:{job.gt}" if job.gt.startswith("/") and not Path(job.gt).exists() else job.gt
        ref = load_trajectory(spec)
        result.score = score(Trajectory(ref.stamps_ns, ref.poses, job.gt), Trajectory(
            result.trajectory.stamps_ns, result.trajectory.poses, "odom"))
        result.metrics["accuracy"] = result.score.to_dict()
    return result


def _run(reader: LogReader, cfg: OdomConfig, progress: Progress | None) -> OdomResult:
    notes: list[str] = []
    t_wall = time.perf_counter()
    inp = cfg.input
    lidar = select_topic(reader, "lidar", inp.lidar_topic)
    deskew = cfg.resolved_deskew()
    needs_imu = cfg.prior == "imu" or deskew == "imu"
    imu = select_topic(reader, "imu", inp.imu_topic, required=False)
    if imu is None and needs_imu:
        what = "--prior imu" if cfg.prior == "imu" else "--deskew imu"
        raise InputError(
            f"{reader.path}: no IMU topic (sensor_msgs/Imu) for {what}; run LiDAR-only with "
            "--prior constant-velocity --deskew constant-velocity, or name the topic with --imu-topic"
        )
    use_imu = imu is not None and needs_imu
    wheel = None
    if cfg.use_wheel or cfg.prior == "wheel":
        wheel = select_topic(reader, "wheel", inp.wheel_topic, required=cfg.prior == "wheel")
    planar = cfg.planar if cfg.planar is not None else reader.topics[lidar].msgtype == LASERSCAN
    convention = parse_time_convention(inp.point_time) if inp.point_time else None
    total = reader.topics[lidar].count

    stream = SensorStream(reader, {"lidar": lidar, "imu": imu if use_imu else None, "wheel": wheel},
                          convention=convention, strict=False)
    offset_ns = cfg.calibration.imu_time_offset_ns
    tree = read_static_frames(reader)
    odo: LioOdometry | None = None
    extr_info: dict = {}
    pending: deque[PointCloud] = deque()
    stamps, poses = [], []
    t_read = 0.0
    done = 0

    def process_ready(now_ns: int | None) -> None:
        nonlocal done
        while pending:
            cloud = pending[0]
            covered = odo.imu_until_ns()
            if use_imu and now_ns is not None:
                # wait for IMU covering the scan, and before the first scan for the start-up window
                need = cloud.end_ns if odo.state is not None else max(cloud.end_ns, odo.imu_from_ns() + init_ns)
                if (covered is None or covered < need) and now_ns - need < _IMU_WAIT_NS:
                    return
            pending.popleft()
            res = odo.process(cloud)
            done += 1
            if progress:
                progress(done, total)
            if res is not None:
                stamps.append(res.stamp_ns)
                poses.append(res.pose)

    init_ns = int(cfg.static_init_s * 1e9)
    early_imu: list[ImuBatch] = []  # IMU before the first scan: kept for the start-up estimate
    tick = time.perf_counter()
    for rec in stream:
        t_read += time.perf_counter() - tick
        if odo is None and rec.kind == "lidar":
            imu_frame = (early_imu[0].frame_id if early_imu else "") if use_imu else None
            ext, extr_info = resolve_extrinsics(tree, cfg.calibration, inp.base_frame, imu_frame, rec.data.frame_id, notes)
            odo = LioOdometry(cfg, ext, use_imu=use_imu, planar=planar,
                              gyro_bias=cfg.calibration.gyro_bias_radps, accel_bias=cfg.calibration.accel_bias_mps2)
            for b in early_imu:
                odo.add_imu(b)
        if rec.kind == "imu":
            batch: ImuBatch = rec.data
            if offset_ns:
                batch = ImuBatch(batch.frame_id, batch.stamps_ns + offset_ns, batch.gyro_radps, batch.accel_mps2)
            if odo is None:
                early_imu.append(batch)
            else:
                odo.add_imu(batch)
        elif rec.kind == "wheel" and odo is not None:
            odo.add_wheel(rec.data)
        elif rec.kind == "lidar":
            pending.append(rec.data)
        if odo is not None:
            process_ready(rec.stamp_ns)
        tick = time.perf_counter()
    if odo is None:
        raise InputError(f"{reader.path}: {lidar}: no scan with valid points in the log")
    process_ready(None)
    wall = time.perf_counter() - t_wall
    if not stamps:
        raise InputError(f"{reader.path}: {lidar}: no scan could be used (all had fewer than "
                         f"{cfg.registration.min_points} valid points)")
    P = np.stack(poses)
    if cfg.frame == "lidar":
        P = P @ odo.ext.T_base_lidar
    elif cfg.frame == "imu":
        P = P @ odo.ext.T_base_imu
    resolved = with_overrides(cfg, {
        "input.format": reader.format, "input.lidar_topic": lidar, "input.imu_topic": imu if use_imu else None,
        "input.wheel_topic": wheel, "input.base_frame": extr_info["base_frame"], "deskew": deskew, "planar": planar,
    }, "resolved configuration")
    st = odo.stats
    span_s = (stamps[-1] - stamps[0]) * 1e-9 if len(stamps) > 1 else 0.0
    metrics = {
        "log": str(reader.path),
        "format": reader.format,
        "topics": {"lidar": lidar, "imu": imu if use_imu else None, "wheel": wheel},
        "mode": "planar (SE(2))" if planar else "3D (SE(3))",
        "frame": cfg.frame,
        "pose_stamp": f"scan {cfg.scan_reference}: each pose is at the instant its scan was de-skewed to",
        "deskew": deskew,
        "prior": cfg.prior,
        "fusion": cfg.fusion.method if use_imu else "none (no IMU)",
        "initialisation": odo.start.reason if odo.start else None,
        "initialisation_static": bool(odo.start.static) if odo.start else None,
        "extrinsics": extr_info,
        "scans": st.counts(),
        "stream": stream.stats.to_dict(),
        "voxel_size_m": odo.voxel_size_m,
        "final_gyro_bias_radps": odo.state.bg.tolist() if odo.state is not None else None,
        "final_accel_bias_mps2": odo.state.ba.tolist() if odo.state is not None else None,
        "time_s": {"read_decode": round(t_read, 4), **{k: round(v, 4) for k, v in st.times_s.items()},
                   "total": round(wall, 4)},
        "trajectory_span_s": span_s,
        "real_time_factor": (span_s / wall) if wall > 0 else None,
        "notes": notes,
    }
    traj = Trajectory(np.asarray(stamps, dtype=np.int64), P, f"{reader.path}:odom", "odom")
    return OdomResult(traj, resolved, st, odo.start.reason if odo.start else None, metrics, notes)
