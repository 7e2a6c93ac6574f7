"""``lio deskew``: a copy of a log with motion-compensated LiDAR clouds (flags -> DeskewJob -> run_deskew ->
write_deskew -> print)."""

from __future__ import annotations

from pathlib import Path
from typing import Annotated, Literal, Optional

import typer

from ..config import load_config, with_overrides
from ..config.deskew import MOTIONS, OUTPUT_FORMATS, DeskewConfig
from ..io.messages.pointcloud import parse_time_convention
from ..io.files.atomic import check_writable
from ..io.files.output_paths import refuse_shared_outputs
from ..io.logs.detect import input_paths
from ..jobs.deskew import DeskewJob, DeskewResult, check_deskew_outputs, run_deskew, write_deskew
from .common import (FLAG, INPUT_PANEL, MOTION_PANEL, OUTPUT_PANEL, RUN_PANEL, BaseFrameOpt, CalibOpt, ConfigOpt,
                     ForceOpt, ImuTimeOffsetOpt, ImuTopicOpt, InputFormat, JsonOpt, LidarTopicOpt, LioCommand,
                     LogArg, PointTimeOpt, PreferCalibOpt, QuietOpt, config_default, job_progress, next_step, note,
                     one_of, plural, prefer_calib_override, print_json, shown, warn)

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
de-skewed scans, voxel-downsampled, and FILE-stem.png beside it, the map seen from above.

[bold]Examples[/bold]

  lio deskew walk.bag walk_deskewed.bag
  lio odom walk_deskewed.bag --deskew none   # de-skewed once only
  lio odom run.mcap -o run.tum
  lio deskew run.mcap run_deskewed.mcap --trajectory run.tum --map run.ply
  lio deskew scans_ros2/ deskewed_ros2 --topic-suffix _deskewed
  lio deskew lidar_only.bag out.bag --motion constant-velocity
"""

Motion = Literal[MOTIONS]
TrajectoryFrame = Literal["base", "lidar"]
OutputFormat = Literal[OUTPUT_FORMATS]
Reference = Literal["end", "start"]


def _default(field: str):
    return config_default(DeskewConfig, field)


def deskew(
    log: LogArg,
    out: Annotated[Path, typer.Argument(metavar="OUT", help="Output log: .bag (ROS 1), .mcap, or a ROS 2 bag folder.", show_default=False)],
    input_format: Annotated[Optional[InputFormat], typer.Option("--input-format", metavar=one_of(InputFormat), help="Input format, overriding detection.", show_default=False, rich_help_panel=INPUT_PANEL)] = None,
    lidar_topic: LidarTopicOpt = None,
    imu_topic: ImuTopicOpt = None,
    point_time: PointTimeOpt = None,
    base_frame: BaseFrameOpt = None,
    motion: Annotated[Optional[Motion], typer.Option("--motion", metavar=one_of(Motion), help=shown("Where the motion comes from; auto: --trajectory if given, else the IMU.", _default("motion")), show_default=False, rich_help_panel=MOTION_PANEL)] = None,
    trajectory: Annotated[Optional[str], typer.Option("--trajectory", help="Motion from this trajectory of the base: a TUM file (e.g. from lio odom) or LOG:/topic.", show_default=False, rich_help_panel=MOTION_PANEL)] = None,
    trajectory_frame: Annotated[Optional[TrajectoryFrame], typer.Option("--trajectory-frame", metavar=one_of(TrajectoryFrame), help=shown("The frame whose poses --trajectory holds.", _default("trajectory.frame")), show_default=False, rich_help_panel=MOTION_PANEL)] = None,
    calib: CalibOpt = None,
    prefer_calib: PreferCalibOpt = False,
    imu_time_offset: ImuTimeOffsetOpt = None,
    fmt: Annotated[Optional[OutputFormat], typer.Option("--format", metavar=one_of(OutputFormat), help=shown("Output format.", "OUT's suffix, else the input's"), show_default=False, rich_help_panel=OUTPUT_PANEL)] = None,
    reference: Annotated[Optional[Reference], typer.Option("--reference", metavar=one_of(Reference), help=shown("The instant each cloud is de-skewed to and stamped with.", _default("reference")), show_default=False, rich_help_panel=OUTPUT_PANEL)] = None,
    topic_suffix: Annotated[Optional[str], typer.Option("--topic-suffix", help="Write de-skewed clouds to TOPIC+SUFFIX and keep the raw topic.", show_default=False, rich_help_panel=OUTPUT_PANEL)] = None,
    map_file: Annotated[Optional[Path], typer.Option("--map", help="Also write the world-frame map of the de-skewed scans (.ply or .pcd).", show_default=False, rich_help_panel=OUTPUT_PANEL)] = None,
    map_voxel: Annotated[Optional[float], typer.Option("--map-voxel", help=shown("Voxel size of --map, m.", _default("map_voxel_m")), show_default=False, rich_help_panel=OUTPUT_PANEL)] = None,
    as_json: JsonOpt = False,
    force: ForceOpt = False,
    strict: Annotated[bool, typer.Option("--strict", metavar=FLAG, help="Refuse (exit 2) a scan the motion does not cover or without a valid point, instead of copying it unchanged.", rich_help_panel=RUN_PANEL)] = False,
    config: ConfigOpt = None,
    quiet: QuietOpt = False,
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
    extra_inputs = tuple(p for p in (config, calib) if p is not None)
    check_deskew_outputs(job, extra_inputs)
    preview = None if map_file is None else _check_preview(job, extra_inputs)
    with job_progress("de-skewing", quiet) as update:
        result = run_deskew(job, progress=update)
    written = write_deskew(result, job.out, force)
    if preview is not None:
        from ..io.files.point_clouds import read_point_map
        from ..plots.map import write_map_preview

        write_map_preview(read_point_map(map_file), preview, force, cfg.map_voxel_m)
        written.append(preview)
    for n in result.notes:
        warn(n)
    _report(result, written, quiet)
    next_step(_odom_args(result, lidar_topic, imu_topic, calib, imu_time_offset, base_frame), quiet)
    if as_json:
        print_json(result.metrics)


def _check_preview(job: DeskewJob, extra_inputs: tuple[Path, ...]) -> Path:
    """Where --map's top view goes, checked before the work."""
    from ..plots.map import preview_path

    preview = preview_path(job.map)
    refuse_shared_outputs([("the output log", job.out), ("the map (--map)", job.map), ("the map's top view", preview)])
    check_writable(preview, job.force, [*input_paths(job.log), *extra_inputs])
    return preview


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
                no_args_is_help=True, cls=LioCommand)(deskew)
