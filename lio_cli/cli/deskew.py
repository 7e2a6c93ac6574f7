"""``lio deskew``: a copy of a log with motion-compensated LiDAR clouds (flags -> DeskewJob -> run_deskew ->
write_deskew -> print)."""

from __future__ import annotations

from pathlib import Path
from typing import Annotated, Optional

import typer

from ..config import load_config, with_overrides
from ..config.deskew import DeskewConfig
from ..io.messages.pointcloud import parse_time_convention
from ..jobs.deskew import DeskewJob, DeskewResult, check_deskew_outputs, run_deskew, write_deskew
from .common import (BaseFrameOpt, ConfigOpt, ForceOpt, ImuTopicOpt, JsonOpt, LidarTopicOpt, LogArg, PointTimeOpt,
                     PreferCalibOpt, QuietOpt, job_progress, next_step, note, plural, prefer_calib_override,
                     print_json, warn)

HELP = """Write OUT: a copy of LOG in which every cloud of the LiDAR topic is motion-compensated (de-skewed)
and everything else is copied untouched.

[bold]The de-skewed cloud[/bold]: same topic (or TOPIC+--topic-suffix, keeping the raw one beside it), same
frame_id, same fields, point order and count (intensity, ring... stay with their points; invalid points stay
invalid, byte for byte). x/y/z are expressed in the sensor frame at one reference instant: the scan's last
valid point (--reference end, default) or its first (--reference start); the header stamp is set to that
instant and a relative per-point time field (time, t, offset_time...) is rewritten relative to it (absolute
ones stay). A LaserScan topic is written as a PointCloud2 (x, y, z, intensity, time: one point per beam, NaN
where there is no return). Scans the motion does not cover, or without a valid point, are copied unchanged
and counted (--strict refuses them).

[bold]Everything else[/bold]: other topics' messages byte for byte with their record times, their
connection metadata (definitions, hashes, latching, QoS) and /tf_static. ROS 1 messages (a ROS 1 bag or
a ROS 1 encoded MCAP file) written as a ROS 2 bag or an MCAP file, or back, are converted field for field
instead, from the definitions the input stores (counted in metrics.json). An MCAP output is always ROS 2
(CDR), which rosbags reads.

[bold]Motion[/bold] (metrics.json says which): --trajectory FILE (TUM or LOG:/topic of the base, e.g.
from lio odom; interpolated on SE(3)); else the IMU: lio's IMU-primed odometry runs, and each sweep
gets the gyro's rotation (with the bias and clock offset the odometry had at that scan) and the
odometry's translation; else, asked for with --motion constant-velocity, LiDAR-only odometry. On two
or more cores a second process writes the output beside the odometry, taking each scan's pose as it
settles (the same bytes; a run takes about the odometry's time).

OUT's format: --format, else its suffix (.bag ROS 1, .mcap MCAP), else the input's (a ROS 2 bag folder).
Also written: OUT-stem.deskew.metrics.json (scans written and skipped and why, motion source, times) and
OUT-stem.deskew.config.yaml (`--config` it to repeat the run). --map FILE.ply|.pcd: the world-frame map of all
de-skewed scans, voxel-downsampled.

[bold]Examples[/bold]

  lio deskew walk.bag walk_deskewed.bag && lio odom walk_deskewed.bag --deskew none   # de-skewed once only

  lio odom run.mcap -o run.tum && lio deskew run.mcap run_deskewed.mcap --trajectory run.tum --map run.ply

  lio deskew scans_ros2/ deskewed_ros2 --topic-suffix _deskewed --reference start

  lio deskew lidar_only.bag out.bag --motion constant-velocity
"""


def deskew(
    log: LogArg,
    out: Annotated[Path, typer.Argument(help="Output log: .bag (ROS 1), .mcap, or a ROS 2 bag folder.", show_default=False)],
    trajectory: Annotated[Optional[str], typer.Option("--trajectory", help="Motion from this trajectory of the base (TUM file or LOG:/topic), e.g. from lio odom.", show_default=False)] = None,
    trajectory_frame: Annotated[Optional[str], typer.Option("--trajectory-frame", help="base | lidar: the frame whose poses --trajectory holds (default base).", show_default=False)] = None,
    motion: Annotated[Optional[str], typer.Option("--motion", help="auto | trajectory | imu | constant-velocity (default auto: --trajectory, else the IMU).", show_default=False)] = None,
    reference: Annotated[Optional[str], typer.Option("--reference", help="end | start: the instant each cloud is de-skewed to and stamped with (default end).", show_default=False)] = None,
    topic_suffix: Annotated[Optional[str], typer.Option("--topic-suffix", help="Write de-skewed clouds to TOPIC+SUFFIX and keep the raw topic.", show_default=False)] = None,
    fmt: Annotated[Optional[str], typer.Option("--format", help="Output format: ros1, ros2, ros2-mcap, mcap (default: from OUT's suffix, else the input's).", show_default=False)] = None,
    input_format: Annotated[Optional[str], typer.Option("--input-format", help="Input format, overriding detection: ros1, ros2 or mcap.", show_default=False)] = None,
    map_file: Annotated[Optional[Path], typer.Option("--map", help="Also write the world-frame map of the de-skewed scans (.ply or .pcd).", show_default=False)] = None,
    map_voxel: Annotated[Optional[float], typer.Option("--map-voxel", help="Voxel size of --map in metres (default 0.1).", show_default=False)] = None,
    strict: Annotated[bool, typer.Option("--strict", help="Refuse (exit 2) instead of copying unchanged a scan the motion does not cover or without a valid point or sweep.")] = False,
    config: ConfigOpt = None,
    calib: Annotated[Optional[Path], typer.Option("--calib", help="Calibration YAML: T_base_imu, T_base_lidar, imu_time_offset_s (used where /tf_static is silent).", show_default=False)] = None,
    prefer_calib: PreferCalibOpt = False,
    imu_time_offset: Annotated[Optional[float], typer.Option("--imu-time-offset", help="Seconds added to IMU stamps to put them on the LiDAR's clock (as imu_time_offset_s of --calib; overrides it).", show_default=False)] = None,
    base_frame: BaseFrameOpt = None,
    lidar_topic: LidarTopicOpt = None,
    imu_topic: ImuTopicOpt = None,
    point_time: PointTimeOpt = None,
    as_json: JsonOpt = False,
    quiet: QuietOpt = False,
    force: ForceOpt = False,
) -> None:
    cfg = load_config(DeskewConfig, config, calib)
    if point_time is not None:
        parse_time_convention(point_time)  # a bad spec is a usage error now, not after opening the log
    cfg = with_overrides(cfg, {
        "calibration.prefer_file": prefer_calib_override(prefer_calib, calib, config),
        "trajectory.path": trajectory, "trajectory.frame": trajectory_frame, "motion": motion, "reference": reference,
        "topic_suffix": topic_suffix, "output_format": fmt, "input.format": input_format, "map_voxel_m": map_voxel,
        "strict": True if strict else None, "input.lidar_topic": lidar_topic, "input.imu_topic": imu_topic,
        "input.point_time": point_time, "input.base_frame": base_frame, "calibration.imu_time_offset_s": imu_time_offset,
    })
    job = DeskewJob(Path(log), Path(out), cfg, map_file, force)
    check_deskew_outputs(job, tuple(p for p in (config, calib) if p is not None))
    with job_progress("de-skewing", quiet) as update:
        result = run_deskew(job, progress=update)
    written = write_deskew(result, job.out, force)
    for n in result.notes:
        warn(n)
    _report(result, written, quiet)
    next_step(_odom_args(result, lidar_topic, imu_topic, calib, imu_time_offset, base_frame), quiet)
    if as_json:
        print_json(result.metrics)


def _report(result: DeskewResult, written: list[Path], quiet: bool) -> None:
    m = result.metrics
    sc = m["scans"]
    why = "; ".join(f"{n} {reason}" for reason, n in sc["unchanged_why"].items())
    note(f"{m['lidar_topic']}: {sc['deskewed']}/{plural(sc['total'], 'scan')} de-skewed to the scan "
         f"{result.config.reference}"
         + (f" on {m['output_topic']}" if m["output_topic"] != m["lidar_topic"] else "")
         + (f", {sc['unchanged']} copied unchanged ({why})" if sc["unchanged"] else ""), quiet)
    note(f"motion: {m['motion']['description']}", quiet)
    copied = m["copied_topics"]
    as_stored, converted = sum(copied["as_stored"].values()), sum(copied["converted"].values())
    parts = ([f"{plural(as_stored, 'message')} copied as stored"] if as_stored or not converted else []) + \
        ([f"{plural(converted, 'message')} converted to {result.format}"] if converted else [])
    note(f"other topics: {', '.join(parts)}", quiet)
    if "map" in m:
        note(f"map: {plural(m['map']['points'], 'point')} in {m['map']['path']}", quiet)
    note(f"{m['time_s']['total']:.1f} s wall, {m['real_time_factor'] or 0:.1f}x real time; wrote {written[0]} "
         f"({result.format}), {', '.join(str(p) for p in written[1:])}", quiet)
    # its per-point times still say when each point was taken: an odometry that de-skews by them does it twice
    note("its clouds are de-skewed: run odometry on it without de-skewing again (kiss-icp: deskew false)", quiet)


def _odom_args(result: DeskewResult, lidar_topic: str | None, imu_topic: str | None, calib: Path | None,
               imu_time_offset: float | None, base_frame: str | None) -> list[str]:
    """``lio odom``'s arguments for the output: what this run was told about the log, and the de-skewed topic."""
    m = result.metrics
    args = ["odom", str(result.out), "--deskew", "none"]
    if m["output_topic"] != m["lidar_topic"] or lidar_topic is not None:  # raw and de-skewed topics both there
        args += ["--lidar-topic", m["output_topic"]]
    for flag, value in (("--imu-topic", imu_topic), ("--calib", calib), ("--imu-time-offset", imu_time_offset),
                        ("--base-frame", base_frame)):
        if value is not None:
            args += [flag, str(value)]
    return args


def register(app: typer.Typer) -> None:
    app.command("deskew", help=HELP, short_help="A copy of a log with motion-compensated LiDAR clouds.",
                no_args_is_help=True)(deskew)
