"""The writing pass of ``lio deskew``: every record of the log copied or, on the LiDAR topic, de-skewed.

Run after the motion is known (a trajectory, or the odometry's poses in a list) or beside the odometry in a
second process (``deskew_helper``), taking its poses as they settle: the same code, the same bytes.
"""

from __future__ import annotations

import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ...core.deskew.voxel_map import VoxelMap
from ...io.logs.copy import LogCopy
from ...io.files.atomic import check_writable, no_space_as_error, remove_path, replace_path, temp_sibling
from ...io.files.point_clouds import point_map_bytes
from ...io.logs.base import LogReader
from ...io.logs.writer import LogWriter
from .motion import Motion, Progress, RecordFeed, settled_motion
from .scan import ScanPlan, ScanWriter


@dataclass(frozen=True)
class WriteSetup:
    """A run from the odometry's poses, as resolved before the odometry starts: what the writing pass needs
    besides the poses (the helper process gets it first, pickled)."""

    job: object  # DeskewJob
    fmt: str  # output format
    plan: ScanPlan
    source: str  # "imu" or "constant-velocity"
    imu_topic: str | None
    mounting: object  # odom_inputs.Mounting (the writer resolves the IMU's extrinsic through it)
    T_base_lidar: np.ndarray

    def motion(self, batches, final_offset_ns: int | None = None):
        """``settled_motion`` over the odometry's pose ``batches``."""
        return settled_motion(self.job.log, self.job.config, self.source, self.imu_topic, self.mounting,
                              self.T_base_lidar, batches, final_offset_ns)


def write_pass(job, reader: LogReader, fmt: str, plan: ScanPlan, motion: Motion, progress: Progress | None,
               done0: int, total: int, level: Callable[[], np.ndarray] | None = None,
               on_temp: Callable[[Path], None] | None = None,
               before_commit: Callable[[dict], None] | None = None) -> dict:
    """Write ``job.out`` (and ``job.map``) from ``reader``; returns the pass's statistics. ``level``: the
    rotation (4x4) from the motion's world frame to the map's, asked once every pose has come. ``on_temp``:
    told each temporary output before it is made; ``before_commit``: called with the statistics once
    everything is written and closed, before anything is renamed into place (an exception there discards it
    all; after it only the renames remain)."""
    cfg = job.config
    voxels = VoxelMap(cfg.map_voxel_m) if job.map is not None else None
    t0 = time.perf_counter()
    map_tmp = None
    w = LogWriter(job.out, fmt, force=job.force, on_temp=on_temp)
    try:
        with no_space_as_error(job.out):  # a full device mid-log: one line, the temporary removed below
            scans = _write_records(reader, w, plan, motion, cfg, voxels, progress, done0, total)
        t_map = time.perf_counter()
        if voxels is not None:
            points = voxels.points()
            if level is not None:
                A = level()
                points = (points @ A[:3, :3].T.astype(np.float32)) + A[:3, 3].astype(np.float32)
            check_writable(job.map, job.force)
            map_tmp = temp_sibling(job.map)
            if on_temp is not None:
                on_temp(map_tmp)
            with no_space_as_error(job.map):
                map_tmp.write_bytes(point_map_bytes(points, job.map.suffix))
        t_map = time.perf_counter() - t_map
        w.finish()
        stats = scans.summary()
        stats["imu_gap_scans"] = motion.imu_gap_scans
        stats["scan_span_ns"] = scans.span_ns
        stats["copied_topics"] = {"as_stored": scans.copy.copied, "converted": scans.copy.converted}
        if voxels is not None:
            stats["map"] = {"path": str(job.map), "points": len(voxels), "voxel_m": voxels.voxel_m,
                            "frame": "the motion source's world frame"}
        stats["time_s"] = {"write_pass": round(time.perf_counter() - t0, 4), **scans.times(), "map": round(t_map, 4)}
        if before_commit is not None:
            before_commit(stats)
    except BaseException:
        w.abort()
        if map_tmp is not None:
            remove_path(map_tmp)
        raise
    try:
        w.commit()  # from here on only renames
    except BaseException:
        if map_tmp is not None:
            remove_path(map_tmp)
        raise
    if map_tmp is not None:
        replace_path(map_tmp, job.map)
    return stats


def _write_records(reader: LogReader, w: LogWriter, plan: ScanPlan, motion: Motion, cfg, voxels: VoxelMap | None,
                   progress: Progress | None, done0: int, total: int) -> ScanWriter:
    """Every record copied or de-skewed into ``w`` in the log's order; the scans' writer, for its counts."""
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
    if motion.feed is not None:
        motion.feed.drain()  # the odometry's end: scans it placed after the log's last usable cloud
    return scans


__all__ = ["write_pass"]
