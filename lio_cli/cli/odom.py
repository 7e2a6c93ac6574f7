"""``lio odom``: IMU-primed scan matching over a log (flags -> OdomJob -> run_odom -> score_odom -> write_odom ->
print)."""

from __future__ import annotations

import sys
from pathlib import Path
from typing import Annotated, Optional

import typer

from ..config import load_config, with_overrides
from ..config.odom import OdomConfig
from ..errors import ConfigError
from ..io.logs.detect import input_paths
from ..io.messages.pointcloud import parse_time_convention
from ..io.files.trajectory import format_tum
from ..jobs.contract import load_reference
from ..jobs.odom import TAG, DivergedRun, OdomJob, OdomResult, run_odom, score_odom, write_odom
from ..jobs.outputs import check_outputs, default_output
from .common import (BaseFrameOpt, ConfigOpt, ForceOpt, FormatOpt, ImuTopicOpt, JsonOpt, LidarTopicOpt, LogArg,
                     PointTimeOpt, PreferCalibOpt, QuietOpt, WheelTopicOpt, err_console, job_progress, note, plural,
                     prefer_calib_override, print_json, warn)

HELP = """Estimate the trajectory of the base frame from LiDAR scans primed by the IMU (and wheels).

Per scan the IMU state is propagated to the scan's end, every point is de-skewed with the pose at its own
stamp, the scan is registered to a local map (kiss-icp) starting from that prediction, and an EKF (or the
complementary filter) corrects pose, velocity and IMU biases for the next scan. Each output pose is
stamped with the instant its scan was de-skewed to (the scan's end by default).

Writes OUT (TUM: stamp tx ty tz qx qy qz qw; default LOG-stem.odom.tum), and beside it
OUT-stem.odom.metrics.json and OUT-stem.odom.config.yaml (one .odom in the name: walk.tum and
walk.odom.tum both give walk.odom.metrics.json).
The .config.yaml is the whole run (topics, calibration, base frame, options): `lio odom LOG --config
it` repeats the run exactly; flags given with --config override its fields one by one.
With -o - the trajectory goes to stdout and no other file is written.

[bold]Examples[/bold]

  lio odom sample_logs/handheld.bag        # handheld.odom.tum, .metrics.json, .config.yaml

  lio odom run.mcap --lidar-topic /os/points --fusion complementary --alpha 0.9 -o -  | head

  lio odom corridor_ros2/ --prior wheel --json > metrics.json

  lio odom scan2d.bag --prior constant-velocity --deskew constant-velocity   # LiDAR only
"""


def odom(
    log: LogArg,
    output: Annotated[Optional[str], typer.Option("-o", "--output", help="TUM trajectory file, or - for stdout. Default: LOG-stem.odom.tum in the current folder.", show_default=False)] = None,
    config: ConfigOpt = None,
    calib: Annotated[Optional[Path], typer.Option("--calib", help="Calibration YAML: T_base_imu, T_base_lidar, imu_time_offset_s (used where /tf_static is silent).", show_default=False)] = None,
    prefer_calib: PreferCalibOpt = False,
    deskew: Annotated[Optional[str], typer.Option("--deskew", help="imu | constant-velocity | none.", show_default=False)] = None,
    prior: Annotated[Optional[str], typer.Option("--prior", help="Initial guess for registration: imu | constant-velocity | wheel | none.", show_default=False)] = None,
    fusion: Annotated[Optional[str], typer.Option("--fusion", help="ekf | complementary.", show_default=False)] = None,
    alpha: Annotated[Optional[float], typer.Option("--alpha", help="Complementary filter weight of the scan match (0..1).", show_default=False)] = None,
    no_wheel: Annotated[bool, typer.Option("--no-wheel", help="Ignore wheel odometry even if the log has it.")] = False,
    frame: Annotated[Optional[str], typer.Option("--frame", help="Output the trajectory of: base | lidar | imu.", show_default=False)] = None,
    gt: Annotated[Optional[str], typer.Option("--gt", help="Ground truth to score against at the end: a TUM/KITTI file, or a topic of LOG (e.g. /ground_truth). Prints ATE and RPE and adds them to metrics.", show_default=False)] = None,
    planar: Annotated[Optional[bool], typer.Option("--planar/--no-planar", help="Force SE(2) mode (default: on for LaserScan).", show_default=False)] = None,
    imu_time_offset: Annotated[Optional[float], typer.Option("--imu-time-offset", help="Seconds added to IMU stamps to put them on the LiDAR's clock (as imu_time_offset_s of --calib; overrides it).", show_default=False)] = None,
    base_frame: BaseFrameOpt = None,
    lidar_topic: LidarTopicOpt = None,
    imu_topic: ImuTopicOpt = None,
    wheel_topic: WheelTopicOpt = None,
    point_time: PointTimeOpt = None,
    fmt: FormatOpt = None,
    as_json: JsonOpt = False,
    quiet: QuietOpt = False,
    force: ForceOpt = False,
) -> None:
    cfg = load_config(OdomConfig, config, calib)
    if point_time is not None:
        parse_time_convention(point_time)  # a bad spec is a usage error now, not after opening the log
    cfg = with_overrides(cfg, {
        "calibration.prefer_file": prefer_calib_override(prefer_calib, calib, config),
        "deskew": deskew, "prior": prior, "frame": frame, "planar": planar, "fusion.method": fusion,
        "fusion.alpha": alpha, "use_wheel": False if no_wheel else None, "input.format": fmt,
        "input.lidar_topic": lidar_topic, "input.imu_topic": imu_topic, "input.wheel_topic": wheel_topic,
        "input.base_frame": base_frame, "input.point_time": point_time,
        "calibration.imu_time_offset_s": imu_time_offset,
    })

    to_stdout = output == "-"
    if to_stdout and as_json:
        raise ConfigError("-o - and --json both write to stdout; choose one")
    out = None if to_stdout else Path(output) if output else default_output(log, TAG, ".tum")
    if out is not None:
        inputs = [*input_paths(Path(log)), *(p for p in (config, calib) if p is not None)]
        if gt is not None and Path(gt).exists():
            inputs.append(Path(gt))
        check_outputs(out, TAG, force, inputs)

    reference = load_reference(Path(log), gt) if gt is not None else None
    with job_progress("odometry", quiet) as update:
        try:
            result = run_odom(OdomJob(Path(log), cfg), progress=update)
        except DivergedRun as err:  # the trajectory up to where the track was lost is still written
            if err.partial is not None:
                traj = err.partial.trajectory
                if out is None:
                    sys.stdout.write(format_tum(traj.stamps_ns, traj.poses))
                    sys.stdout.flush()
                else:
                    write_odom(err.partial, out, force)
                    err.args = (f"{err}; the trajectory up to there is in {out}",)
            raise
    if reference is not None:
        score_odom(result, reference)
    for n in result.notes:
        warn(n)
    for role, choice in result.roles.items():
        note(f"{role}: {choice['topic'] or '-'} ({choice['why']})", quiet)
    if to_stdout:
        sys.stdout.write(format_tum(result.trajectory.stamps_ns, result.trajectory.poses))
        sys.stdout.flush()
    written = [] if to_stdout else write_odom(result, out, force)
    _report(result, written, quiet)
    if as_json:
        print_json(result.metrics)


def _report(result: OdomResult, written: list[Path], quiet: bool) -> None:
    st, m = result.stats, result.metrics
    note(f"{st.used}/{plural(st.scans, 'scan')} used, {st.degenerate} degenerate, "
         f"{plural(st.registration_failures, 'registration failure')}, {plural(st.imu_gaps, 'IMU gap')}; "
         f"{m['time_s']['total']:.1f} s wall, {m['real_time_factor'] or 0:.1f}x "
         "real time", quiet)
    note(f"start: {result.initialisation}", quiet)
    if result.score is not None:
        a = result.score
        rpe = "-" if a.rpe_trans_rmse_m is None else f"{a.rpe_trans_rmse_m:.4f} m"
        err_console.print(f"against {a.reference}: ATE {a.ate_trans_rmse_m:.4f} m, {a.ate_rot_rmse_deg:.3f} deg "
                          f"({_ALIGNED[a.alignment].format(n=a.matches)}); RPE over {a.rpe_delta}: {rpe}", markup=False)
        if a.note:
            note(a.note, quiet)
    if written:
        note(f"wrote {', '.join(str(p) for p in written)}", quiet)


_ALIGNED = {"se3": "SE(3)-aligned rmse over {n} poses",
            "origin": "rmse over {n} poses aligned at the first: the reference's positions lie on a line or a point"}


def register(app: typer.Typer) -> None:
    app.command("odom", help=HELP, no_args_is_help=True)(odom)
