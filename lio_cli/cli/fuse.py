"""``lio fuse``: offline fusion of odometry, IMU, wheels and GPS into one trajectory (flags -> FuseJob -> run_fuse
-> write_fuse -> print)."""

from __future__ import annotations

import sys
from pathlib import Path
from typing import Annotated, Literal, Optional

import typer

from ..config import load_config, with_overrides
from ..config.fuse import DEFAULT_MAX_MEMORY_MB, FuseConfig, bare_sources, parse_time_offsets, parse_use
from ..errors import ConfigError
from ..io.logs.detect import input_paths
from ..io.files.trajectory import format_tum
from ..jobs.fuse import TAG, FuseJob, FuseRun, check_fuse_outputs, run_fuse, write_fuse
from ..jobs.outputs import default_output
from .common import (CALIBRATION_PANEL, FLAG, INPUT_PANEL, MOTION_PANEL, OUTPUT_PANEL, RUN_PANEL, BaseFrameOpt,
                     ConfigOpt, ForceOpt, FormatOpt, ImuTopicOpt, JsonOpt, LioCommand, LogArg, QuietOpt, WheelTopicOpt,
                     PreferCalibOpt, config_default, job_progress, note, one_of, plural, prefer_calib_override,
                     print_json, shown, warn)

HELP = """Fuse a log's IMU, wheel odometry, GPS and an odometry trajectory into one smooth trajectory of the base.

Reads the log directly and uses the whole recording: a filter (chosen from the data: the 3D error-state EKF,
or the lecture's planar x, y, theta, v, omega, gyro-bias EKF for ground robots near a plane; or the
complementary filter), then by default a smoother that uses every measurement before and after each instant:
a factor graph (preintegrated IMU, wheel, odometry and GPS factors) whenever the accelerometer is used but for
the planar filter on IMU + wheels alone, else the RTS pass over the EKF; --no-smooth keeps the filter alone
(faster). The trajectory starts at the origin of
a z-up world; poses come at --rate HZ or at every IMU sample (exact stamps).

Sources (each optional, at least one of IMU, wheels, odometry): the IMU (gyro, accelerometer, and its own
orientation where the message carries a valid one), wheel odometry (nav_msgs/Odometry or TwistStamped; twist-only
messages are fine), GPS (NavSatFix: fix status and covariance respected, converted to a local ENU frame), and
an odometry trajectory: --odom FILE (TUM/KITTI, e.g. from lio odom) or --odom-topic. Topics are chosen as the
other commands do; --use picks which measurement of which source enters (SOURCE or SOURCE:M1,M2; repeat):
imu:gyro,accel,orientation  wheel:speed|velocity,yaw_rate  odom:pose|delta  gps:position. A bare SOURCE
takes it as the default does (a bare wheel: speed, and the yaw rate where it agrees with the gyro or
without one; a bare imu: its orientation where it follows the gyro), but a bare odom is its poses (increments
beside GPS): without --use, the planar filter takes increments beside wheels that agree with the odometry.

Writes OUT (TUM; default LOG-stem.fuse.tum), OUT-stem.fuse.metrics.json (sources used, updates per source,
rejected measurements and why, time) and OUT-stem.fuse.config.yaml (the whole run: `lio fuse LOG --config it`
repeats it exactly). --cov FILE adds the
per-pose 6x6 covariance, --plot DIR a top view of the sources and the result and speed and yaw rate over time.
With -o - the trajectory goes to stdout and no metrics or config file is written.

[bold]Examples[/bold]

  lio fuse jackal.bag --plot plots/   # writes jackal.fuse.tum
  lio fuse run.mcap --odom run.odom.tum --rate 200 -o fused.tum
  lio fuse long.bag --no-smooth -o filtered.tum     # the filter alone
  lio fuse office.bag --estimator planar --use imu:gyro --use wheel -o -
  lio fuse drive.bag --use imu --use wheel --use gps --json > metrics.json
  lio fuse rover.bag --time-offset gps=-0.3   # GPS fixes stamped 0.3 s late
"""

Estimator = Literal["auto", "ekf", "planar", "complementary"]


def _default(field: str):
    return config_default(FuseConfig, field)


def _check_rate(rate: float | None) -> None:
    if rate is not None and not (rate == rate and rate > 0 and rate != float("inf")):
        raise ConfigError(f"--rate must be a positive number of Hz, got {rate:g}")


def _imu_offset(flag: float | None, given: float | None) -> float | None:
    """--imu-time-offset, or --time-offset imu=S (the same value; both given must agree)."""
    if flag is not None and given is not None and flag != given:
        raise ConfigError(f"--imu-time-offset {flag:g} and --time-offset imu={given:g} disagree; give one")
    return flag if flag is not None else given


def _bare_imu(use: list[str] | None, cfg: FuseConfig) -> bool | None:
    """True where ``--use imu`` names the IMU bare (and nothing configured otherwise): its orientation checked as
    the default selection checks it; else None (not given)."""
    return True if cfg.check_orientation is None and "imu" in bare_sources(use) else None


def _bare_wheel(use: list[str] | None, cfg: FuseConfig) -> bool | None:
    """True where ``--use wheel`` names the wheels bare (and nothing configured otherwise): the wheels as the
    default selection takes them, their yaw rate weighed against the gyro; else None (not given)."""
    return True if cfg.weigh_wheel_yaw is None and "wheel" in bare_sources(use) else None


def fuse_cmd(
    log: LogArg,
    fmt: FormatOpt = None,
    imu_topic: ImuTopicOpt = None,
    wheel_topic: WheelTopicOpt = None,
    gps_topic: Annotated[Optional[str], typer.Option("--gps-topic", help=shown("sensor_msgs/NavSatFix topic.", "the only one"), show_default=False, rich_help_panel=INPUT_PANEL)] = None,
    odom: Annotated[Optional[Path], typer.Option("--odom", help="Odometry to fuse: a TUM or KITTI file (e.g. from lio odom), or LOG:/topic.", show_default=False, rich_help_panel=INPUT_PANEL)] = None,
    odom_topic: Annotated[Optional[str], typer.Option("--odom-topic", help="A pose topic of LOG to fuse as odometry (Odometry, PoseStamped, TransformStamped).", show_default=False, rich_help_panel=INPUT_PANEL)] = None,
    base_frame: BaseFrameOpt = None,
    use: Annotated[Optional[list[str]], typer.Option("--use", metavar="SOURCE[:M,...]", help=shown("Only these sources and measurements enter (repeat), e.g. imu:gyro, wheel:speed,yaw_rate.", "every source found"), show_default=False, rich_help_panel=INPUT_PANEL)] = None,
    estimator: Annotated[Optional[Estimator], typer.Option("--estimator", metavar=one_of(Estimator), help=shown("auto: planar for a wheeled robot near a plane, else ekf; ekf: 3D error-state; planar: SE(2); complementary.", _default("estimator")), show_default=False, rich_help_panel=MOTION_PANEL)] = None,
    smooth: Annotated[Optional[bool], typer.Option("--smooth/--no-smooth", metavar=FLAG, help=shown("Smooth over the whole log (the future as well as the past): factor graph with an accelerometer, else RTS; --no-smooth: the filter alone.", _default("smooth")), show_default=False, rich_help_panel=MOTION_PANEL)] = None,
    accel_noise: Annotated[Optional[float], typer.Option("--accel-noise", help=shown("Accelerometer noise density, m/s^2/sqrt(Hz) (vibration: larger).", _default("noise.accel_noise_density")), show_default=False, rich_help_panel=MOTION_PANEL)] = None,
    gyro_noise: Annotated[Optional[float], typer.Option("--gyro-noise", help=shown("Gyro noise density, rad/s/sqrt(Hz).", _default("noise.gyro_noise_density")), show_default=False, rich_help_panel=MOTION_PANEL)] = None,
    calib: Annotated[Optional[Path], typer.Option("--calib", help="Calibration YAML (lio calibrate): T_base_imu where /tf_static is silent, imu_time_offset_s, biases.", show_default=False, rich_help_panel=CALIBRATION_PANEL)] = None,
    prefer_calib: PreferCalibOpt = False,
    imu_time_offset: Annotated[Optional[float], typer.Option("--imu-time-offset", help="Seconds added to IMU stamps to put them on the other sensors' clock (overrides --calib's imu_time_offset_s).", show_default=False, rich_help_panel=CALIBRATION_PANEL)] = None,
    time_offset: Annotated[Optional[list[str]], typer.Option("--time-offset", metavar="SOURCE=SECONDS", help="Seconds added to a source's stamps, as --imu-time-offset to the IMU's (repeat; SOURCE: wheel, gps, odom, imu), e.g. gps=-0.3 for fixes stamped 0.3 s late; metrics.json's clocks section measures the others' lag against the IMU.", show_default=False, rich_help_panel=CALIBRATION_PANEL)] = None,
    output: Annotated[Optional[str], typer.Option("-o", "--output", help=shown("TUM trajectory file, or - for stdout.", "LOG-stem.fuse.tum"), show_default=False, rich_help_panel=OUTPUT_PANEL)] = None,
    rate: Annotated[Optional[float], typer.Option("--rate", help=shown("Output rate in Hz.", "every IMU sample"), show_default=False, rich_help_panel=OUTPUT_PANEL)] = None,
    cov: Annotated[Optional[Path], typer.Option("--cov", help="Also write each pose's 6x6 covariance (text: stamp and 36 values).", show_default=False, rich_help_panel=OUTPUT_PANEL)] = None,
    plot: Annotated[Optional[Path], typer.Option("--plot", help="Folder for PNGs: top view of the sources and the result; speed and yaw rate over time.", show_default=False, rich_help_panel=OUTPUT_PANEL)] = None,
    as_json: JsonOpt = False,
    force: ForceOpt = False,
    config: ConfigOpt = None,
    max_memory: Annotated[Optional[float], typer.Option("--max-memory", help=shown("Memory budget in MB: a longer run is fused in overlapping chunks.", f"{DEFAULT_MAX_MEMORY_MB:g}"), show_default=False, rich_help_panel=RUN_PANEL)] = None,
    quiet: QuietOpt = False,
) -> None:
    _check_rate(rate)
    offsets = parse_time_offsets(time_offset or [])
    imu_time_offset = _imu_offset(imu_time_offset, offsets.pop("imu", None))
    cfg = load_config(FuseConfig, config, calib)
    cfg = with_overrides(cfg, {
        "calibration.prefer_file": prefer_calib_override(prefer_calib, calib, config),
        "input.format": fmt, "input.imu_topic": imu_topic, "input.wheel_topic": wheel_topic,
        "input.gps_topic": gps_topic, "input.odom_topic": odom_topic, "input.odom_file": str(odom) if odom else None,
        "input.base_frame": base_frame, "use": parse_use(use) if use else None, "estimator": estimator,
        "smooth": smooth, "rate_hz": rate, "noise.accel_noise_density": accel_noise,
        "noise.gyro_noise_density": gyro_noise, "calibration.imu_time_offset_s": imu_time_offset,
        "max_memory_mb": max_memory, "time_offsets_s": {**cfg.time_offsets_s, **offsets} if offsets else None,
        "weigh_wheel_yaw": _bare_wheel(use, cfg), "check_orientation": _bare_imu(use, cfg),
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
    parts = [s["summary"] for s in m["sources"].values() if "summary" in s]
    note(f"estimator: {m['estimator']} ({m['estimator_reason']})", quiet)
    sm = m["smoother"]
    if sm["kind"] != "factor_graph":  # the default's own case goes without saying; a fallback or none says why
        note(f"smoother: {(sm['kind'] or 'none').replace('_', ' ')} ({sm['why']})", quiet)
    est = m["estimator"] + {"factor_graph": " + factor graph", "rts": " + RTS"}.get(sm["kind"] or "", "")
    chunks = m["memory"]["chunks"]
    note(f"{plural(m['output']['poses'], 'pose')} ({m['output']['stamps']}), {est}: {'; '.join(parts)}"
         + (f"; fused in {chunks} chunks (memory budget {m['memory']['budget_mb']:g} MB)" if chunks > 1 else ""), quiet)
    note(f"{m['time_s']['total']:.2f} s wall, {m['real_time_factor'] or 0:.0f}x real time", quiet)
    if m.get("start"):
        note(f"start: {m['start']}", quiet)
    check = (m.get("core") or {}).get("wheel_check")
    if check:
        note(f"wheels: {check['why']}", quiet)
    yaw = (m.get("core") or {}).get("wheel_yaw_check")
    if yaw:
        note(f"wheel yaw rate: {yaw['why']}", quiet)
    rest = (m.get("core") or {}).get("rest")
    if rest:
        note(f"at rest: {rest['why']}", quiet)
    if written:
        note(f"wrote {', '.join(str(p) for p in written)}", quiet)


def register(app: typer.Typer) -> None:
    app.command("fuse", help=HELP, no_args_is_help=True, cls=LioCommand)(fuse_cmd)
