"""The ``deskew`` job: write a copy of a log whose LiDAR clouds are motion-compensated.

``DeskewJob`` (log, output, configuration, optional map) -> ``run_deskew`` -> ``DeskewResult`` ->
``write_deskew``. The job checks every output location first, takes the motion from its source (``motion``: a
first pass over the log when the odometry provides it), then streams the log once more into the output: every
record of another topic copied as stored (``LogCopy``), every cloud of the LiDAR topic de-skewed into the sensor
frame at its reference instant (``scan``). The run writes the output log and the map as it streams (each to a
temporary sibling, renamed at its end: a failed run leaves neither); ``write_deskew`` then places
``OUT-stem.deskew.metrics.json`` and ``OUT-stem.deskew.config.yaml`` beside the log.
"""

from __future__ import annotations

import copy
import time
from dataclasses import dataclass, field, replace
from pathlib import Path

import yaml

from ...config import dump_model, with_overrides
from ...config.deskew import DeskewConfig
from ...errors import InputError
from ...io.logs.detect import detect_format, input_paths
from ...io.files.atomic import atomic_outputs, check_writable, remove_path
from ...io.files.point_clouds import check_map_suffix
from ...io.logs.base import LogReader
from ...io.logs.reader import open_log
from ...io.sensors.tf import read_static_frames
from ...io.sensors.topics import choose_topic
from ...io.logs.writer import FILE_SUFFIXES, SUFFIX_FORMATS
from .helper import Helper
from .motion import Progress, check_covered, resolve_motion, run_odometry, trajectory_motion
from .scan import plan_scans
from .write import WriteSetup, write_pass
from ..odom.inputs import Mounting
from ..outputs import json_text, sidecars

TAG = "deskew"  # in the name of every file a run writes beside its log


@dataclass(frozen=True)
class DeskewJob:
    """Everything one ``lio deskew`` run needs. ``map``: also write the world-frame map (.ply or .pcd)."""

    log: Path
    out: Path
    config: DeskewConfig = field(default_factory=DeskewConfig)
    map: Path | None = None
    force: bool = False
    helper: bool = True  # write beside the odometry in a second process (when there are two cores)


@dataclass
class DeskewResult:
    out: Path
    format: str  # of the output log
    config: DeskewConfig  # resolved: repeats the run
    metrics: dict
    notes: list[str] = field(default_factory=list)


def output_format(out: Path, asked: str | None, reader: LogReader) -> str:
    """``--format``, else OUT's suffix (.bag ros1, .mcap mcap), else the input's format (and ROS 2 storage).
    A ROS 1 bag or MCAP file must carry its suffix (rosbags and MCAP tools open by it); a ROS 2 bag is a folder."""
    fmt = _output_format(out, asked, reader)
    want = FILE_SUFFIXES.get(fmt)
    if want is not None and Path(out).suffix != want:
        got = f"'{Path(out).suffix}'" if Path(out).suffix else "no suffix"
        raise InputError(f"{out}: {'a ROS 1 bag' if fmt == 'ros1' else 'an MCAP file'} needs the {want} suffix "
                         f"(OUT has {got}; readers go by it): name it {Path(out).stem}{want} (a ROS 2 bag, "
                         "--format ros2, is a folder and needs none)")
    return fmt


def _output_format(out: Path, asked: str | None, reader: LogReader) -> str:
    if asked is not None:
        return asked
    if Path(out).suffix in SUFFIX_FORMATS:
        return SUFFIX_FORMATS[Path(out).suffix]
    if reader.format == "ros2":
        try:
            meta = yaml.safe_load((reader.paths[0] / "metadata.yaml").read_text())["rosbag2_bagfile_information"]
            return "ros2-mcap" if meta.get("storage_identifier") == "mcap" else "ros2"
        except (OSError, KeyError, TypeError, yaml.YAMLError):
            return "ros2"
    return reader.format



def output_in(folder: Path, log: Path, cfg: DeskewConfig) -> Path:
    """The output log of a run into ``folder`` (``lio batch``): ``deskew`` with the suffix of its format (the
    input's unless asked: a folder of split ROS 1 bags gives a .bag), a folder for a ROS 2 bag."""
    fmt = cfg.output_format or cfg.input.format
    if fmt is None:
        try:
            fmt, _ = detect_format(Path(log))
        except InputError:  # the run itself says what is wrong with the log
            fmt = None
    return folder / f"{TAG}{FILE_SUFFIXES.get(fmt or '', '')}"


def check_deskew_outputs(job: DeskewJob, extra_inputs: tuple[Path, ...] = ()) -> None:
    """Every output may be written and is none of the inputs (before any work)."""
    inputs = [*input_paths(job.log), *extra_inputs]
    path = job.config.trajectory.path
    if path is not None and Path(path).exists():
        inputs.append(Path(path))
    outs = [job.out, *sidecars(Path(job.out), TAG)]
    if job.map is not None:
        check_map_suffix(job.map)
        outs.append(job.map)
    for p in outs:
        check_writable(p, job.force, inputs)


def run_deskew(job: DeskewJob, progress: Progress | None = None) -> DeskewResult:
    """De-skew every cloud of ``job.log``'s LiDAR topic into ``job.out`` (and the map into ``job.map``); the
    metrics and the resolved config are ``write_deskew``'s."""
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
        t_motion = time.perf_counter()
        if source == "trajectory":
            motion, description, details = trajectory_motion(cfg, T_base_lidar)
            t_motion = time.perf_counter() - t_motion
            try:
                stats = write_pass(job, reader, fmt, plan, motion, progress, 0, n_scans, before_commit=lambda st:
                                   check_covered(st, motion, cfg.trajectory.path, lidar))
            finally:
                motion.close()
            writing = "after the motion was read"
        else:
            setup = WriteSetup(job, fmt, plan, source, imu_topic, mounting, T_base_lidar)
            helper = Helper.start() if job.helper else None
            stats, odo, t_motion, mounting, writing = _from_odometry(helper, reader, setup, progress, n_scans)
            description, details = odo.description, odo.details
            notes.extend([*odo.notes, *mounting.notes])  # repeats go below
    wall = time.perf_counter() - t_wall
    gaps = stats.pop("imu_gap_scans")
    stats.pop("scan_span_ns", None)
    notes = list(dict.fromkeys(notes))  # the odometry and this run resolve the same extrinsics
    resolved = with_overrides(cfg, {
        "input.lidar_topic": lidar, "input.imu_topic": imu_topic,
        "input.base_frame": mounting.base, "motion": source,
    }, "resolved configuration")
    span_s = reader.duration_ns * 1e-9
    metrics = {
        "command": "deskew", "log": str(job.log), "format": reader.format, "output": str(job.out),
        "output_format": fmt, "lidar_topic": lidar, "output_topic": plan.out_topic,
        "motion": {"source": source, "description": description, **details,
                   **({"imu_topic": imu_topic, "imu_gap_scans": gaps} if source == "imu" else {})},
        "writing": writing,
        "reference": f"scan {cfg.reference}: each cloud is in the sensor frame at its {'last' if cfg.reference == 'end' else 'first'} "
                     "valid point's instant, which is its new header stamp",
        "point_time": plan.describe(), "extrinsics": mounting.describe(), **stats,
        "time_s": {"motion": round(t_motion, 4), **stats.pop("time_s"), "total": round(wall, 4)},
        "log_duration_s": round(span_s, 4), "real_time_factor": round(span_s / wall, 3) if wall > 0 else None,
        "notes": notes,
    }
    return DeskewResult(job.out, fmt, resolved, metrics, notes)


def write_deskew(result: DeskewResult, out: Path, force: bool) -> list[Path]:
    """Finish a run: its resolved config and metrics beside the output log ``out`` (the job's, already written);
    returns every file of the run (the log, the map, the metrics, the config)."""
    metrics_path, config_path = sidecars(Path(out), TAG)
    try:
        with atomic_outputs([config_path, metrics_path], force) as (config_tmp, metrics_tmp):
            config_tmp.write_text(dump_model(result.config))
            metrics_tmp.write_text(json_text(result.metrics))
    except BaseException:  # a run's files are all there or none is: the log written without them goes too
        remove_path(out)
        raise
    written_map = [Path(result.metrics["map"]["path"])] if "map" in result.metrics else []
    return [Path(out), *written_map, metrics_path, config_path]


def _from_odometry(helper: Helper | None, reader: LogReader, setup: WriteSetup, progress: Progress | None,
                   n_scans: int) -> tuple:
    """The odometry, and the writing pass over its settled poses: beside it in the helper process when there
    is one, else after it. After it too when the clock offset the odometry measured by its end asks for every
    scan to be written with that offset (see ``PoseFeed``): the helper's files are then discarded."""
    job, mounting = setup.job, setup.mounting
    t_motion = time.perf_counter()
    # the odometry's scans, then the writer's (those it has left after the odometry)
    odo_progress = None if progress is None else (lambda done, total: progress(done, 2 * n_scans))
    try:
        if helper is not None:
            helper.send("setup", setup)
        odo = run_odometry(job.log, job.config, setup.source, odo_progress, reader,
                           None if helper is None else (lambda batch: helper.send("poses", batch)))
    except BaseException:
        if helper is not None:
            helper.abort()
        raise
    t_motion = time.perf_counter() - t_motion
    if helper is not None and odo.final_offset_ns is None:
        stats, mounting = helper.finish(odo.level, None if progress is None else
                                        (lambda written: progress(n_scans + written, 2 * n_scans)))
        if progress is not None:
            progress(2 * n_scans, 2 * n_scans)  # its last reports come at most every 0.1 s
        return stats, odo, t_motion, mounting, "beside the odometry, in a second process"
    writing = "after the odometry"
    if helper is not None:
        helper.abort()
        writing += (" (the clock offset it measured by its end differs from what it applied online: every scan "
                    "is written with the final one)")
    # as the helper's copy: what the writing resolves comes after the odometry's notes
    setup = replace(setup, mounting=copy.deepcopy(mounting))
    motion = setup.motion(iter(odo.batches), odo.final_offset_ns)
    try:
        stats = write_pass(job, reader, setup.fmt, setup.plan, motion, progress, n_scans, 2 * n_scans,
                           lambda: odo.level)
    finally:
        motion.close()
    return stats, odo, t_motion, setup.mounting, writing


__all__ = ["DeskewJob", "DeskewResult", "check_deskew_outputs", "output_format", "output_in", "run_deskew",
           "write_deskew"]
