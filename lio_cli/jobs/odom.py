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
from ..core.odometry import Diverged, LioOdometry, OdomStats
from ..errors import InputError, ProcessingError
from ..evaluation.scoring import Score, score
from ..io.decode import LASERSCAN
from ..io.pointcloud import parse_time_convention
from ..io.reader import LogReader, open_log
from ..io.sources import load_trajectory
from ..io.stream import SensorStream
from ..io.tf import FrameTree, read_static_frames
from ..io.topics import select_topic
from ..model.calibration import Calibration
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


def resolve_extrinsic(tree: FrameTree, calib: Calibration, base: str, name: str, frame: str,
                      notes: list[str]) -> tuple[np.ndarray, str]:
    """``name`` (T_base_imu or T_base_lidar) from /tf_static by frame_id, else the calibration, else identity."""
    T = tree.lookup(base, frame) if frame else None
    if T is not None:
        return T, f"/tf_static ({base} -> {frame})"
    if calib.matrix(name) is not None:
        return calib.matrix(name), "--calib"
    notes.append(f"no extrinsic {name} ({base} -> {frame or '?'}) in /tf_static or --calib: identity assumed")
    return np.eye(4), "identity (assumed)"


class DivergedRun(ProcessingError):
    """The track was lost for good; ``partial`` holds the trajectory up to there (None if no scan was used)."""

    def __init__(self, message: str, partial: OdomResult | None) -> None:
        super().__init__(message)
        self.partial = partial


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
    base = inp.base_frame or next((b for b in BASE_FRAME_NAMES if b in tree.frames), "base")
    extr_info: dict = {"base_frame": base, "T_base_imu": "not used (no IMU in this run)"}
    odo: LioOdometry | None = None
    pending: deque[PointCloud] = deque()
    early_imu: list[ImuBatch] = []  # IMU that arrived before the first scan
    t_read = 0.0
    done = 0

    def process_ready(now_ns: int | None) -> None:
        nonlocal done
        while pending:
            cloud = pending[0]
            covered = odo.imu_until_ns()
            # wait (a bounded stretch of log time) for IMU covering the scan, so its motion can be predicted
            if use_imu and now_ns is not None and (covered is None or covered < cloud.end_ns) \
                    and now_ns - cloud.end_ns < _IMU_WAIT_NS:
                return
            pending.popleft()
            odo.process(cloud)
            done += 1
            if progress:
                progress(done, total)

    def mount_imu(batch: ImuBatch) -> None:
        # the IMU's extrinsic by its own frame_id, whenever its first message arrives
        T, extr_info["T_base_imu"] = resolve_extrinsic(tree, cfg.calibration, base, "T_base_imu", batch.frame_id, notes)
        odo.set_imu_extrinsic(T)

    tick = time.perf_counter()
    try:
        for rec in stream:
            t_read += time.perf_counter() - tick
            if odo is None and rec.kind == "lidar":
                T_bl, extr_info["T_base_lidar"] = resolve_extrinsic(tree, cfg.calibration, base, "T_base_lidar",
                                                                    rec.data.frame_id, notes)
                odo = LioOdometry(cfg, T_bl, use_imu=use_imu, planar=planar,
                                  gyro_bias=cfg.calibration.gyro_bias_radps, accel_bias=cfg.calibration.accel_bias_mps2)
                if early_imu:
                    mount_imu(early_imu[0])
                for b in early_imu:
                    odo.add_imu(b)
            if rec.kind == "imu":
                batch: ImuBatch = rec.data
                if offset_ns:
                    batch = ImuBatch(batch.frame_id, batch.stamps_ns + offset_ns, batch.gyro_radps, batch.accel_mps2)
                if odo is None:
                    early_imu.append(batch)
                else:
                    if not odo.imu_mounted:
                        mount_imu(batch)
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
    except Diverged as err:
        partial = _result(reader, cfg, odo, stream, lidar, imu if use_imu else None, wheel, deskew, planar,
                          extr_info, notes, t_read, time.perf_counter() - t_wall) if odo.poses else None
        raise DivergedRun(f"{reader.path}: {err}", partial) from err
    if not odo.poses:
        raise InputError(f"{reader.path}: {lidar}: no scan could be used (all had fewer than "
                         f"{cfg.registration.min_points} valid points)")
    return _result(reader, cfg, odo, stream, lidar, imu if use_imu else None, wheel, deskew, planar,
                   extr_info, notes, t_read, time.perf_counter() - t_wall)


def _result(reader, cfg: OdomConfig, odo: LioOdometry, stream: SensorStream, lidar, imu, wheel, deskew, planar,
            extr_info, notes, t_read, wall) -> OdomResult:
    stamps = odo.stamps_ns
    P = odo.output_alignment() @ np.stack(odo.poses)
    if cfg.frame == "lidar":
        P = P @ odo.ext.T_base_lidar
    elif cfg.frame == "imu":
        P = P @ odo.ext.T_base_imu
    resolved = with_overrides(cfg, {
        "input.format": reader.format, "input.lidar_topic": lidar, "input.imu_topic": imu,
        "input.wheel_topic": wheel, "input.base_frame": extr_info["base_frame"], "deskew": deskew, "planar": planar,
    }, "resolved configuration")
    st = odo.stats
    start = _start_summary(odo, imu is not None)
    span_s = (stamps[-1] - stamps[0]) * 1e-9 if len(stamps) > 1 else 0.0
    metrics = {
        "log": str(reader.path),
        "format": reader.format,
        "topics": {"lidar": lidar, "imu": imu, "wheel": wheel},
        "mode": "planar (SE(2))" if planar else "3D (SE(3))",
        "frame": cfg.frame,
        "pose_stamp": f"scan {cfg.scan_reference}: each pose is at the instant its scan was de-skewed to",
        "deskew": deskew,
        "prior": cfg.prior,
        "fusion": cfg.fusion.method if imu else "none (no IMU)",
        "initialisation": start["reason"],
        "initialisation_static": start["static"],
        "start": start,
        "events": odo.events,
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
    return OdomResult(traj, resolved, st, start["reason"], metrics, notes)


def _start_summary(odo: LioOdometry, with_imu: bool) -> dict:
    """Which start happened, after how many LiDAR-only scans, and the initial velocity (output world frame)."""
    b = odo.start
    if b is None:
        reason = ("LiDAR only (no IMU in this run): level start at the origin" if not with_imu else
                  "the IMU state never started (the log is shorter than the start-up window or the IMU never "
                  "covered it): LiDAR-only scans, levelled by the mean specific force")
        return {"kind": "lidar-only", "static": None, "scans": 0, "initial_velocity_mps": None, "reason": reason}
    v = odo.output_alignment()[:3, :3] @ b.v_world
    return {"kind": "standing" if b.static else "moving", "static": b.static, "scans": b.scans,
            "initial_velocity_mps": [round(float(x), 4) for x in v], "speed_mps": round(float(np.linalg.norm(v)), 4),
            "stamp_ns": b.stamp_ns, "reason": b.reason}
