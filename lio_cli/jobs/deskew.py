"""The ``deskew`` job: write a copy of a log whose LiDAR clouds are motion-compensated.

``DeskewJob`` (log, output, configuration, optional map) -> ``run_deskew`` -> ``DeskewResult``. The job
checks every output location first, takes the motion from its source (``deskew_motion``: a first pass over
the log when the odometry provides it), then streams the log once more into the output: every record of
another topic copied as stored (``LogCopy``), every cloud of the LiDAR topic de-skewed into the sensor frame
at its reference instant (``deskew_scan``). The output log, ``OUT-stem.metrics.json``, ``OUT-stem.config.yaml``
and the map are each written to a temporary sibling and renamed: a failed run leaves none of them.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field
from pathlib import Path

import yaml

from ..config import dump_model, with_overrides
from ..config.deskew import DeskewConfig
from ..core.voxel_map import VoxelMap
from ..io.detect import input_paths
from ..io.files import atomic_output, check_writable
from ..io.log_copy import LogCopy, mcap_profile
from ..io.map_files import check_map_suffix, write_point_map
from ..io.reader import LogReader, open_log
from ..io.tf import read_static_frames
from ..io.topics import choose_topic
from ..io.writer import LogWriter
from .deskew_motion import Motion, Progress, RecordFeed, odometry_motion, resolve_motion, trajectory_motion
from .deskew_scan import ScanPlan, ScanWriter, plan_scans
from .odom_inputs import Mounting
from .outputs import beside, json_text


@dataclass(frozen=True)
class DeskewJob:
    """Everything one ``lio deskew`` run needs. ``map``: also write the world-frame map (.ply or .pcd)."""

    log: Path
    out: Path
    config: DeskewConfig = field(default_factory=DeskewConfig)
    map: Path | None = None
    force: bool = False


@dataclass
class DeskewResult:
    out: Path
    format: str  # of the output log
    config: DeskewConfig  # resolved: repeats the run
    metrics: dict
    notes: list[str] = field(default_factory=list)


def output_format(out: Path, asked: str | None, reader: LogReader) -> str:
    """``--format``, else OUT's suffix (.bag ros1, .mcap mcap), else the input's format (and ROS 2 storage)."""
    if asked is not None:
        return asked
    suffix = Path(out).suffix
    if suffix in (".bag", ".mcap"):
        return {".bag": "ros1", ".mcap": "mcap"}[suffix]
    if reader.format == "ros2":
        try:
            meta = yaml.safe_load((reader.paths[0] / "metadata.yaml").read_text())["rosbag2_bagfile_information"]
            return "ros2-mcap" if meta.get("storage_identifier") == "mcap" else "ros2"
        except (OSError, KeyError, TypeError, yaml.YAMLError):
            return "ros2"
    return reader.format


def sidecars(out: Path) -> tuple[Path, Path]:
    """(metrics, resolved config) written beside the output log."""
    return beside(Path(out), ".metrics.json"), beside(Path(out), ".config.yaml")


def check_deskew_outputs(job: DeskewJob, extra_inputs: tuple[Path, ...] = ()) -> None:
    """Every output may be written and is none of the inputs (before any work)."""
    inputs = [*input_paths(job.log), *extra_inputs]
    path = job.config.trajectory.path
    if path is not None and Path(path).exists():
        inputs.append(Path(path))
    outs = [job.out, *sidecars(job.out)]
    if job.map is not None:
        check_map_suffix(job.map)
        outs.append(job.map)
    for p in outs:
        check_writable(p, job.force, inputs)


def run_deskew(job: DeskewJob, progress: Progress | None = None) -> DeskewResult:
    """De-skew every cloud of ``job.log``'s LiDAR topic into ``job.out``; write metrics, config and map."""
    t_wall = time.perf_counter()
    check_deskew_outputs(job)
    cfg, notes = job.config, []
    with open_log(job.log, cfg.input.format) as reader:
        fmt = output_format(job.out, cfg.output_format, reader)
        lidar = choose_topic(reader, "lidar", cfg.input.lidar_topic).topic
        plan = plan_scans(reader, lidar, cfg)
        source, imu_topic = resolve_motion(cfg, reader)
        mounting = Mounting.of(read_static_frames(reader), cfg.calibration, cfg.input.base_frame, notes)
        T_base_lidar = mounting.resolve("T_base_lidar", plan.frame_id)
        n_scans = reader.topics[lidar].count
        passes = 1 if source == "trajectory" else 2
        t_motion = time.perf_counter()
        if source == "trajectory":
            motion = trajectory_motion(cfg, T_base_lidar)
        else:
            odo_progress = None if progress is None else (lambda done, total: progress(done, passes * n_scans))
            motion = odometry_motion(job.log, cfg, source, imu_topic, mounting, T_base_lidar, odo_progress, reader)
            notes.extend(n for n in motion.details.pop("notes") if n not in notes)
        t_motion = time.perf_counter() - t_motion
        try:
            stats = _write(job, reader, fmt, plan, motion, progress, (passes - 1) * n_scans, passes * n_scans)
        finally:
            motion.close()
    wall = time.perf_counter() - t_wall
    notes = list(dict.fromkeys(notes))  # the odometry and this run resolve the same extrinsics
    resolved = with_overrides(cfg, {
        "input.format": reader.format, "input.lidar_topic": lidar, "input.imu_topic": imu_topic,
        "input.base_frame": mounting.base, "motion": source, "output_format": fmt,
    }, "resolved configuration")
    span_s = reader.duration_ns * 1e-9
    metrics = {
        "command": "deskew", "log": str(job.log), "format": reader.format, "output": str(job.out),
        "output_format": fmt, "lidar_topic": lidar, "output_topic": plan.out_topic,
        "motion": {"source": source, "description": motion.description, **motion.details,
                   **({"imu_topic": imu_topic, "imu_gap_scans": motion.imu_gap_scans} if source == "imu" else {})},
        "reference": f"scan {cfg.reference}: each cloud is in the sensor frame at its {'last' if cfg.reference == 'end' else 'first'} "
                     "valid point's instant, which is its new header stamp",
        "point_time": plan.describe(), "extrinsics": mounting.describe(), **stats,
        "time_s": {"motion": round(t_motion, 4), **stats.pop("time_s"), "total": round(wall, 4)},
        "log_duration_s": round(span_s, 4), "real_time_factor": round(span_s / wall, 3) if wall > 0 else None,
        "notes": notes,
    }
    metrics_path, config_path = sidecars(job.out)
    with atomic_output(config_path, job.force) as tmp:
        tmp.write_text(dump_model(resolved))
    with atomic_output(metrics_path, job.force) as tmp:
        tmp.write_text(json_text(metrics))
    return DeskewResult(job.out, fmt, resolved, metrics, notes)


def _write(job: DeskewJob, reader: LogReader, fmt: str, plan: ScanPlan, motion: Motion, progress: Progress | None,
           done0: int, total: int) -> dict:
    """The writing pass: every record copied or, on the LiDAR topic, de-skewed; returns the pass's statistics."""
    cfg = job.config
    voxels = VoxelMap(cfg.map_voxel_m) if job.map is not None else None
    t0 = time.perf_counter()
    with LogWriter(job.out, fmt, force=job.force, mcap_profile=mcap_profile(reader)) as w:
        copy = LogCopy(reader, w)
        scans = ScanWriter(reader, w, copy, plan, motion, cfg, voxels)
        for conn in reader.connections:  # output connections in the input's order
            if conn.topic != plan.topic or cfg.topic_suffix:
                copy.output(conn)
            if conn.topic == plan.topic:
                scans.output(conn)
        done = done0
        records = reader.records()
        if motion.imu is not None:  # one read of the log: the IMU window reads ahead through the same records
            records = RecordFeed(reader, motion.imu.topic)
            motion.imu.attach(records)
        for rec in records:
            if rec.connection.topic != plan.topic:
                copy.copy(rec)
                continue
            if cfg.topic_suffix:
                copy.copy(rec)
            scans.write(rec)
            done += 1
            if progress is not None:
                progress(done, total)
    t_map = time.perf_counter()
    if voxels is not None:
        write_point_map(job.map, voxels.points(), job.force)
    t_map = time.perf_counter() - t_map
    stats = scans.summary()
    stats["copied_topics"] = {"as_stored": copy.copied, "converted": copy.converted}
    if voxels is not None:
        stats["map"] = {"path": str(job.map), "points": len(voxels), "voxel_m": voxels.voxel_m,
                        "frame": "the motion source's world frame"}
    stats["time_s"] = {"write_pass": round(time.perf_counter() - t0, 4), **scans.times(), "map": round(t_map, 4)}
    return stats


__all__ = ["DeskewJob", "DeskewResult", "check_deskew_outputs", "output_format", "run_deskew", "sidecars"]
