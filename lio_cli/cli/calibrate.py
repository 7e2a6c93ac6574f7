"""``lio calibrate``: the calibration every other command reads with --calib, from one log
(flags -> CalibrateJob -> run_calibrate -> write_calibrate -> print)."""

from __future__ import annotations

import sys
from pathlib import Path
from typing import Annotated, Optional

import typer

from ..config import load_calibration, load_config, with_overrides
from ..config.calibrate import CalibrateConfig
from ..errors import ConfigError
from ..io.messages.pointcloud import parse_time_convention
from ..jobs.calibrate import (TAG, CalibrateJob, CalibrateResult, check_calibrate_outputs, run_calibrate,
                              write_calibrate, yaml_text)
from ..jobs.calibrate.report import format_table
from ..jobs.outputs import default_output
from .common import (CALIBRATION_PANEL, FLAG, INPUT_PANEL, OUTPUT_PANEL, BaseFrameOpt, ConfigOpt, ForceOpt, FormatOpt,
                     ImuTopicOpt, JsonOpt, LidarTopicOpt, LioCommand, LogArg, PointTimeOpt, QuietOpt, WheelTopicOpt,
                     err_console, job_progress, note, prefer_calib_override, print_json, shown)

HELP = """Estimate, from one log, the calibration that odom, deskew and fuse read with --calib, and write it
to OUT.yaml (default: LOG's name + .calib.yaml in the current folder).

[bold]What it estimates[/bold], each only when the log holds what it needs (otherwise a line "not estimated:
X: WHY" says why and how to move to get it, and the YAML names it in a comment and leaves it out):
the IMU at rest (a still stretch found automatically, or --still START:END): gyro bias, accelerometer bias
along gravity, white-noise densities; the LiDAR-IMU time offset, rotation and translation (LiDAR odometry of
the log itself, LiDAR-only first, then IMU-primed with the first estimates, against the gyro and the
accelerometer); wheel odometry speed and yaw-rate scales (and radius and baseline with --wheel-radius and
--wheel-baseline); with --allan the Allan variance of a static IMU log (--plot DIR draws it, --kalibr FILE
writes Kalibr's imu.yaml).

[bold]The YAML[/bold]: T_base_imu and T_base_lidar map sensor points into the base frame (4x4, metres);
T_base_lidar is taken from /tf_static (else --calib, else identity: base = LiDAR); imu_time_offset_s is ADDED
to IMU stamps to put them on the LiDAR's clock; biases in the IMU frame; 1-sigmas beside the values.

On stderr: a table of each value, its 1-sigma and its difference from --calib (else /tf_static) in degrees,
cm and ms. Also written: OUT-stem.calib.metrics.json and OUT-stem.calib.config.yaml (with -o - the YAML goes to stdout
and neither is written; --kalibr and --plot still write theirs). Bad input (no IMU, no still
stretch where one is needed, clocks that disagree, nothing at all estimable): one line, exit 2, nothing
written; anything estimated: exit 0.

[bold]Examples[/bold]

  lio calibrate walk.bag                        # writes walk.calib.yaml
  lio odom walk.bag --calib walk.calib.yaml
  lio calibrate robot.mcap --wheel-radius 0.08 --wheel-baseline 0.42
  lio calibrate car.mcap --imu-time-offset 0    # keep a known offset
  lio calibrate imu_2h.mcap --allan --plot allan/ --kalibr imu.yaml
"""


def calibrate(
    log: LogArg,
    fmt: FormatOpt = None,
    lidar_topic: LidarTopicOpt = None,
    imu_topic: ImuTopicOpt = None,
    wheel_topic: WheelTopicOpt = None,
    point_time: PointTimeOpt = None,
    base_frame: BaseFrameOpt = None,
    still: Annotated[Optional[str], typer.Option("--still", metavar="START:END", help=shown("Seconds after the first IMU sample where the IMU rests.", "found"), show_default=False, rich_help_panel=INPUT_PANEL)] = None,
    allan: Annotated[bool, typer.Option("--allan", metavar=FLAG, help="Allan variance of the whole log (a static IMU recording of hours): noise and random walks.", rich_help_panel=INPUT_PANEL)] = False,
    calib: Annotated[Optional[Path], typer.Option("--calib", help="A calibration YAML to compare with; its T_base_lidar is used where /tf_static is silent, its imu_time_offset_s where the motion cannot time the IMU.", show_default=False, rich_help_panel=CALIBRATION_PANEL)] = None,
    prefer_calib: Annotated[bool, typer.Option("--prefer-calib", metavar=FLAG, help="Run the passes with --calib's T_base_lidar even where /tf_static gives one (config: prior.prefer_file: true); a note says how far apart the two are either way.", rich_help_panel=CALIBRATION_PANEL)] = False,
    imu_time_offset: Annotated[Optional[float], typer.Option("--imu-time-offset", help="Seconds added to IMU stamps to put them on the LiDAR's clock, kept where the motion cannot time the IMU; measured otherwise.", show_default=False, rich_help_panel=CALIBRATION_PANEL)] = None,
    wheel_radius: Annotated[Optional[float], typer.Option("--wheel-radius", help="Nominal wheel radius in m: estimate the true one.", show_default=False, rich_help_panel=CALIBRATION_PANEL)] = None,
    wheel_baseline: Annotated[Optional[float], typer.Option("--wheel-baseline", help="Nominal wheel baseline in m: estimate the true one.", show_default=False, rich_help_panel=CALIBRATION_PANEL)] = None,
    output: Annotated[Optional[str], typer.Option("--output", "-o", help=shown("Calibration YAML, or - for stdout (then no metrics or config file).", "LOG-stem.calib.yaml"), show_default=False, rich_help_panel=OUTPUT_PANEL)] = None,
    plot: Annotated[Optional[Path], typer.Option("--plot", help="Folder for the Allan deviation plot (needs --allan).", show_default=False, rich_help_panel=OUTPUT_PANEL)] = None,
    kalibr: Annotated[Optional[Path], typer.Option("--kalibr", help="Also write Kalibr's imu.yaml here (needs --allan).", show_default=False, rich_help_panel=OUTPUT_PANEL)] = None,
    as_json: JsonOpt = False,
    force: ForceOpt = False,
    config: ConfigOpt = None,
    quiet: QuietOpt = False,
) -> None:
    cfg = load_config(CalibrateConfig, config, calib, "prior")
    if imu_time_offset is None and calib is not None and "imu_time_offset_s" in load_calibration(calib).model_fields_set:
        imu_time_offset = cfg.prior.imu_time_offset_s  # given, even as 0 (which looks like no --calib at all)
    if point_time is not None:
        parse_time_convention(point_time)  # a bad spec is a usage error now, not after opening the log
    cfg = with_overrides(cfg, {
        "prior.prefer_file": prefer_calib_override(prefer_calib, calib, config),
        "still": still, "allan": True if allan else None, "wheel_radius_m": wheel_radius,
        "wheel_baseline_m": wheel_baseline, "input.format": fmt, "input.lidar_topic": lidar_topic,
        "input.imu_topic": imu_topic, "input.wheel_topic": wheel_topic, "input.base_frame": base_frame,
        "input.point_time": point_time, "imu_time_offset_s": imu_time_offset,
    })
    to_stdout = output == "-"
    if to_stdout and as_json:
        raise ConfigError("-o - and --json both write to stdout; choose one")
    out = None if to_stdout else Path(output) if output is not None else default_output(log, TAG, ".yaml")
    job = CalibrateJob(Path(log), out, cfg, plot, kalibr, force, tuple(p for p in (config, calib) if p is not None))
    check_calibrate_outputs(job)
    with job_progress("calibrating", quiet) as update:
        result = run_calibrate(job, progress=update)
    written = write_calibrate(result, job.out, force, job.kalibr, job.plot_dir)
    _report(result, written, quiet)
    if to_stdout:
        sys.stdout.write(yaml_text(result.calibration, result.metrics["not_estimated"]))
        sys.stdout.flush()
    if as_json:
        print_json({k: result.metrics[k] for k in ("log", "output", "topics", "reference", "calibration", "table",
                                                    "not_estimated", "notes", "time_s")})


def _report(result: CalibrateResult, written: list[Path], quiet: bool) -> None:
    m = result.metrics
    for role, topic in m["topics"].items():
        note(f"{role}: {topic or '-'}", quiet)
    if m["lidar_trajectory"]:
        note(f"LiDAR trajectory: {m['lidar_trajectory']}", quiet)
    if not quiet:
        for line in format_table(result.table, result.reference):
            err_console.print(line, markup=False, highlight=False)
    for s in result.skipped:
        err_console.print(s.line(), markup=False)
    for n in result.notes:
        note(f"note: {n}", quiet)
    where = [*(["the calibration to stdout"] if m["output"] == "-" else []), *(str(p) for p in written)]
    note(f"wrote {', '.join(where)}; {m['time_s']['total']:.1f} s wall", quiet)


def register(app: typer.Typer) -> None:
    app.command("calibrate", help=HELP, short_help="Calibration (IMU, LiDAR-IMU, wheels) from one log.",
                no_args_is_help=True, cls=LioCommand)(calibrate)
