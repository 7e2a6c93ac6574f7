"""``lio fuse``: offline fusion of odometry, IMU, wheels and GPS into one trajectory (flags -> FuseJob -> run_fuse
-> write_fuse -> print)."""

from __future__ import annotations

import sys
from pathlib import Path
from typing import Annotated, Optional

import typer

from ..config import load_config, with_overrides
from ..config.fuse import FuseConfig, parse_use
from ..errors import ConfigError
from ..io.logs.detect import input_paths
from ..io.files.trajectory import format_tum
from ..jobs.fuse import TAG, FuseJob, FuseRun, check_fuse_outputs, run_fuse, write_fuse
from ..jobs.outputs import default_output
from .common import (BaseFrameOpt, ConfigOpt, ForceOpt, FormatOpt, ImuTopicOpt, JsonOpt, LogArg, PreferCalibOpt,
                     QuietOpt, WheelTopicOpt, job_progress, note, plural, prefer_calib_override, print_json, warn)

HELP = """Fuse a log's IMU, wheel odometry, GPS and an odometry trajectory into one smooth trajectory of the base.

Reads the log directly and uses the whole recording: the error-state EKF (3D; or --estimator planar, the
lecture's x, y, theta, v, omega, gyro-bias filter for ground robots; or the complementary filter), and with
--smooth an RTS smoother over the EKF that uses every measurement before and after each instant. The
trajectory starts at the origin of a z-up world; poses come at --rate HZ or at every IMU sample (exact stamps).

Sources (each optional, at least one of IMU, wheels, odometry): the IMU (gyro, accelerometer, and its own
orientation where the message carries a valid one), wheel odometry (nav_msgs/Odometry or TwistStamped; twist-only
messages are fine), GPS (NavSatFix: fix status and covariance respected, converted to a local ENU frame), and
an odometry trajectory: --odom FILE (TUM/KITTI, e.g. from lio odom) or --odom-topic. Topics are chosen as the
other commands do; --use picks which measurement of which source enters (SOURCE or SOURCE:M1,M2; repeat):
imu:gyro,accel,orientation  wheel:speed|velocity,yaw_rate  odom:pose|delta  gps:position.

Writes OUT (TUM; default LOG-stem.fuse.tum), OUT-stem.fuse.metrics.json (sources used, updates per source,
rejected measurements and why, time) and OUT-stem.fuse.config.yaml (the whole run: `lio fuse LOG --config it`
repeats it exactly). --cov FILE adds the
per-pose 6x6 covariance, --plot DIR a top view of the sources and the result and speed and yaw rate over time.
With -o - the trajectory goes to stdout and no metrics or config file is written.

[bold]Examples[/bold]

  lio fuse jackal.bag --plot plots/        # jackal.fuse.tum, .metrics.json, .config.yaml

  lio fuse run.mcap --odom run_odom.tum --rate 200 --smooth -o fused.tum --cov fused.cov

  lio fuse office.bag --estimator planar --use imu:gyro --use wheel:speed,yaw_rate -o -

  lio fuse drive.bag --gps-topic /gps/fix --use imu --use wheel --use gps --json > metrics.json
"""


def _check_rate(rate: float | None) -> None:
    if rate is not None and not (rate == rate and rate > 0 and rate != float("inf")):
        raise ConfigError(f"--rate must be a positive number of Hz, got {rate:g}")


def fuse_cmd(
    log: LogArg,
    output: Annotated[Optional[str], typer.Option("-o", "--output", help="TUM trajectory file, or - for stdout. Default: LOG-stem.fuse.tum in the current folder.", show_default=False)] = None,
    config: ConfigOpt = None,
    calib: Annotated[Optional[Path], typer.Option("--calib", help="Calibration YAML (lio calibrate): T_base_imu where /tf_static is silent, imu_time_offset_s, biases.", show_default=False)] = None,
    prefer_calib: PreferCalibOpt = False,
    odom: Annotated[Optional[Path], typer.Option("--odom", help="Odometry trajectory to fuse: TUM or KITTI file (e.g. from lio odom), or LOG:/topic.", show_default=False)] = None,
    odom_topic: Annotated[Optional[str], typer.Option("--odom-topic", help="Pose source of the log to fuse as odometry (Odometry, PoseStamped, TransformStamped).", show_default=False)] = None,
    gps_topic: Annotated[Optional[str], typer.Option("--gps-topic", help="sensor_msgs/NavSatFix topic (default: the only one).", show_default=False)] = None,
    use: Annotated[Optional[list[str]], typer.Option("--use", help="SOURCE or SOURCE:M1,M2 (repeat): only these sources and measurements enter. Default: every source found, the core's selection.", show_default=False)] = None,
    estimator: Annotated[Optional[str], typer.Option("--estimator", help="ekf (3D error-state) | planar (SE(2)) | complementary.", show_default=False)] = None,
    smooth: Annotated[Optional[bool], typer.Option("--smooth/--no-smooth", help="RTS smoother over the EKF (uses the future as well as the past).", show_default=False)] = None,
    rate: Annotated[Optional[float], typer.Option("--rate", help="Output rate in Hz (default: every IMU sample).", show_default=False)] = None,
    cov: Annotated[Optional[Path], typer.Option("--cov", help="Also write the per-pose 6x6 covariance (text: stamp and 36 values).", show_default=False)] = None,
    plot: Annotated[Optional[Path], typer.Option("--plot", help="Folder for PNGs: top view of the sources and the fused trajectory; speed and yaw rate over time.", show_default=False)] = None,
    accel_noise: Annotated[Optional[float], typer.Option("--accel-noise", help="Accelerometer noise density, m/s^2/sqrt(Hz) (vibration: larger).", show_default=False)] = None,
    gyro_noise: Annotated[Optional[float], typer.Option("--gyro-noise", help="Gyro noise density, rad/s/sqrt(Hz).", show_default=False)] = None,
    imu_time_offset: Annotated[Optional[float], typer.Option("--imu-time-offset", help="Seconds added to IMU stamps to put them on the other sensors' clock (as imu_time_offset_s of --calib; overrides it).", show_default=False)] = None,
    base_frame: BaseFrameOpt = None,
    max_memory: Annotated[Optional[float], typer.Option("--max-memory", help="Estimation memory budget in MB; a longer run is fused in overlapping chunks, one that chunks cannot fit is refused before fusing (default 1024).", show_default=False)] = None,
    imu_topic: ImuTopicOpt = None,
    wheel_topic: WheelTopicOpt = None,
    fmt: FormatOpt = None,
    as_json: JsonOpt = False,
    quiet: QuietOpt = False,
    force: ForceOpt = False,
) -> None:
    _check_rate(rate)
    cfg = load_config(FuseConfig, config, calib)
    cfg = with_overrides(cfg, {
        "calibration.prefer_file": prefer_calib_override(prefer_calib, calib, config),
        "input.format": fmt, "input.imu_topic": imu_topic, "input.wheel_topic": wheel_topic,
        "input.gps_topic": gps_topic, "input.odom_topic": odom_topic, "input.odom_file": str(odom) if odom else None,
        "input.base_frame": base_frame, "use": parse_use(use) if use else None, "estimator": estimator,
        "smooth": smooth, "rate_hz": rate, "noise.accel_noise_density": accel_noise,
        "noise.gyro_noise_density": gyro_noise, "calibration.imu_time_offset_s": imu_time_offset,
        "max_memory_mb": max_memory,
    })
    to_stdout = output == "-"
    if to_stdout and as_json:
        raise ConfigError("-o - and --json both write to stdout; choose one")
    out = None if to_stdout else Path(output) if output else default_output(log, TAG, ".tum")
    inputs = [*input_paths(Path(log)), *(p for p in (config, calib) if p is not None)]
    if cfg.input.odom_file and Path(cfg.input.odom_file).exists():
        inputs.append(Path(cfg.input.odom_file))
    check_fuse_outputs(out, force, inputs, cov, plot)

    with job_progress("fusing", quiet) as update:
        run = run_fuse(FuseJob(Path(log), cfg, covariance=cov is not None), progress=update)
    for n in run.notes:
        warn(n)
    for src, role in run.roles.items():
        note(f"{src}: {role.get('topic') or role.get('file') or '-'} ({role['why']})", quiet)
    if to_stdout:
        sys.stdout.write(format_tum(run.trajectory.stamps_ns, run.trajectory.poses))
        sys.stdout.flush()
    written = write_fuse(run, out, force, cov, plot)
    _report(run, written, quiet)
    if as_json:
        print_json(run.metrics)


def _report(run: FuseRun, written: list[Path], quiet: bool) -> None:
    m = run.metrics
    parts = []
    for src, s in m["sources"].items():
        if "updates" not in s:
            continue
        rej = sum(r["count"] for r in s["rejected"].values())
        why = ", ".join(f"{r['count']} {k}" for k, r in s["rejected"].items())
        parts.append(f"{src} {plural(s['updates'], 'update')}" + (f", {rej} rejected ({why})" if rej else ""))
    est = m["estimator"] + (" + smoother" if m["smoothed"] else "")
    chunks = m["memory"]["chunks"]
    note(f"{plural(m['output']['poses'], 'pose')} ({m['output']['stamps']}), {est}: {'; '.join(parts)}"
         + (f"; fused in {chunks} chunks (memory budget {m['memory']['budget_mb']:g} MB)" if chunks > 1 else ""), quiet)
    note(f"{m['time_s']['total']:.2f} s wall, {m['real_time_factor'] or 0:.0f}x real time", quiet)
    if m.get("start"):
        note(f"start: {m['start']}", quiet)
    if written:
        note(f"wrote {', '.join(str(p) for p in written)}", quiet)


def register(app: typer.Typer) -> None:
    app.command("fuse", help=HELP, no_args_is_help=True)(fuse_cmd)
