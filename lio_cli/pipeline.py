"""``run_odometry``: read a log's stream, resolve extrinsics, drive :class:`LioOdometry`, gather metrics."""

from __future__ import annotations

import time
from collections import deque
from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np

from .config import Calibration, OdomConfig
from .errors import InputError
from .imu import Extrinsics
from .io.decode import LASERSCAN
from .io.logs import LogReader
from .io.records import ImuBatch, PointCloud
from .io.stream import SensorStream, select_topic
from .io.tf import FrameTree, read_static_frames
from .odometry import LioOdometry

BASE_FRAME_NAMES = ("base_link", "base", "base_footprint")
_IMU_WAIT_NS = 500_000_000  # a scan waits at most this long (log time) for IMU covering its end


@dataclass
class OdomRun:
    stamps_ns: np.ndarray
    poses: np.ndarray  # (N,4,4) of the output frame
    metrics: dict
    notes: list[str] = field(default_factory=list)


def resolve_extrinsics(tree: FrameTree, calib: Calibration | None, base_frame: str | None, imu_frame: str | None,
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
        elif calib is not None and getattr(calib, name) is not None:
            found[name], source[name] = np.asarray(getattr(calib, name), dtype=np.float64), "--calib"
        else:
            found[name], source[name] = np.eye(4), "identity (assumed)"
            notes.append(f"no extrinsic {name} ({base} -> {frame or '?'}) in /tf_static or --calib: identity assumed")
    return Extrinsics(found["T_base_imu"], found["T_base_lidar"]), {"base_frame": base, **source}


def run_odometry(reader: LogReader, cfg: OdomConfig, *, lidar_topic: str | None = None, imu_topic: str | None = None,
                 wheel_topic: str | None = None, calib: Calibration | None = None, base_frame: str | None = None,
                 convention=None, progress: Callable[[float], None] | None = None) -> OdomRun:
    notes: list[str] = []
    t_wall = time.perf_counter()
    lidar = select_topic(reader, "lidar", lidar_topic)
    needs_imu = cfg.prior == "imu" or cfg.deskew == "imu"
    imu = select_topic(reader, "imu", imu_topic, required=False)
    if imu is None and needs_imu:
        what = "--prior imu" if cfg.prior == "imu" else "--deskew imu"
        raise InputError(
            f"{reader.path}: no IMU topic (sensor_msgs/Imu) for {what}; run LiDAR-only with "
            "--prior constant-velocity --deskew constant-velocity, or name the topic with --imu-topic"
        )
    use_imu = imu is not None and needs_imu
    wheel = None
    if cfg.use_wheel or cfg.prior == "wheel":
        wheel = select_topic(reader, "wheel", wheel_topic, required=cfg.prior == "wheel")
    planar = cfg.planar if cfg.planar is not None else reader.topics[lidar].msgtype == LASERSCAN

    stream = SensorStream(reader, {"lidar": lidar, "imu": imu if use_imu else None, "wheel": wheel},
                          convention=convention, strict=False)
    offset_ns = int(round((calib.imu_time_offset_s if calib else 0.0) * 1e9))
    tree = read_static_frames(reader)
    odo: LioOdometry | None = None
    extr_info: dict = {}
    pending: deque[PointCloud] = deque()
    stamps, poses = [], []
    t_read = 0.0

    def process_ready(now_ns: int | None) -> None:
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
            if progress:
                progress(1)
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
            ext, extr_info = resolve_extrinsics(tree, calib, base_frame, imu_frame, rec.data.frame_id, notes)
            odo = LioOdometry(cfg, ext, use_imu=use_imu, planar=planar,
                              gyro_bias=calib.gyro_bias_radps if calib else None,
                              accel_bias=calib.accel_bias_mps2 if calib else None)
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
    st = odo.stats
    span_s = (stamps[-1] - stamps[0]) * 1e-9 if len(stamps) > 1 else 0.0
    metrics = {
        "log": str(reader.path),
        "format": reader.format,
        "topics": {"lidar": lidar, "imu": imu if use_imu else None, "wheel": wheel},
        "mode": "planar (SE(2))" if planar else "3D (SE(3))",
        "frame": cfg.frame,
        "pose_stamp": f"scan {cfg.scan_reference}: each pose is at the instant its scan was de-skewed to",
        "deskew": cfg.deskew,
        "prior": cfg.prior,
        "fusion": cfg.fusion.method if use_imu else "none (no IMU)",
        "initialisation": odo.start.reason if odo.start else None,
        "initialisation_static": bool(odo.start.static) if odo.start else None,
        "extrinsics": extr_info,
        "scans": {
            "total": st.scans,
            "used": st.used,
            "skipped_few_points": st.skipped_few_points,
            "skipped_out_of_order": st.skipped_out_of_order,
            "registration_failures": st.registration_failures,
            "degenerate": st.degenerate,
            "imu_gaps": st.imu_gaps,
            "wheel_updates": st.wheel_updates,
        },
        "stream": stream.stats.to_dict(),
        "voxel_size_m": odo._kiss.voxel if odo._kiss else None,
        "final_gyro_bias_radps": odo.state.bg.tolist() if odo.state is not None else None,
        "final_accel_bias_mps2": odo.state.ba.tolist() if odo.state is not None else None,
        "time_s": {"read_decode": round(t_read, 4), **{k: round(v, 4) for k, v in st.times_s.items()},
                   "total": round(wall, 4)},
        "trajectory_span_s": span_s,
        "real_time_factor": (span_s / wall) if wall > 0 else None,
        "notes": notes,
    }
    return OdomRun(np.asarray(stamps, dtype=np.int64), P, metrics, notes)
