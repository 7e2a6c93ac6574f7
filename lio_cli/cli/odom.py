"""``lio odom``: IMU-primed scan matching over a log."""

from __future__ import annotations

import json
import sys
from pathlib import Path
from typing import Annotated, Optional

import typer

from ..config import dump_config, load_calibration, load_config
from ..errors import ConfigError
from ..io.files import atomic_output, check_writable
from ..io.logs import open_log
from ..io.pointcloud import parse_time_convention
from ..io.trajectory import format_tum
from ..pipeline import run_odometry
from .common import (FormatOpt, ForceOpt, ImuTopicOpt, JsonOpt, LidarTopicOpt, LogArg, PointTimeOpt, QuietOpt,
                     WheelTopicOpt, err_console, note, print_json, progress_bar, warn)

HELP = """Estimate the trajectory of the base frame from LiDAR scans primed by the IMU (and wheels).

Per scan the IMU state is propagated to the scan's end, every point is de-skewed with the pose at its own
stamp, the scan is registered to a local map (kiss-icp) starting from that prediction, and an EKF (or the
complementary filter) corrects pose, velocity and IMU biases for the next scan. Each output pose is
stamped with the instant its scan was de-skewed to (the scan's end by default).

Writes OUT (TUM: stamp tx ty tz qx qy qz qw), OUT-stem.metrics.json and OUT-stem.config.yaml beside it.
With -o - the trajectory goes to stdout and no other file is written.

[bold]Examples[/bold]

  lio odom sample_logs/handheld.bag -o handheld.tum

  lio odom run.mcap --lidar-topic /os/points --fusion complementary --alpha 0.9 -o -  | head

  lio odom corridor_ros2/ --prior wheel --json > metrics.json

  lio odom scan2d.bag --prior constant-velocity --deskew constant-velocity   # LiDAR only
"""


def odom(
    log: LogArg,
    output: Annotated[Optional[str], typer.Option("-o", "--output", help="TUM trajectory file, or - for stdout. Default: LOG-stem.tum in the current folder.", show_default=False)] = None,
    config: Annotated[Optional[Path], typer.Option("--config", help="YAML configuration (see the .config.yaml a run writes).", show_default=False)] = None,
    calib: Annotated[Optional[Path], typer.Option("--calib", help="Calibration YAML: T_base_imu, T_base_lidar, imu_time_offset_s (used where /tf_static is silent).", show_default=False)] = None,
    deskew: Annotated[Optional[str], typer.Option("--deskew", help="imu | constant-velocity | none.", show_default=False)] = None,
    prior: Annotated[Optional[str], typer.Option("--prior", help="Initial guess for registration: imu | constant-velocity | wheel | none.", show_default=False)] = None,
    fusion: Annotated[Optional[str], typer.Option("--fusion", help="ekf | complementary.", show_default=False)] = None,
    alpha: Annotated[Optional[float], typer.Option("--alpha", help="Complementary filter weight of the scan match (0..1).", show_default=False)] = None,
    no_wheel: Annotated[bool, typer.Option("--no-wheel", help="Ignore wheel odometry even if the log has it.")] = False,
    frame: Annotated[Optional[str], typer.Option("--frame", help="Output the trajectory of: base | lidar | imu.", show_default=False)] = None,
    gt: Annotated[Optional[str], typer.Option("--gt", help="Ground truth to score against at the end: a TUM/KITTI file, or a topic of LOG (e.g. /ground_truth). Prints ATE and RPE and adds them to metrics.", show_default=False)] = None,
    planar: Annotated[Optional[bool], typer.Option("--planar/--no-planar", help="Force SE(2) mode (default: on for LaserScan).", show_default=False)] = None,
    base_frame: Annotated[Optional[str], typer.Option("--base-frame", help="Name of the base frame in /tf_static (default: base_link, base or base_footprint).", show_default=False)] = None,
    lidar_topic: LidarTopicOpt = None,
    imu_topic: ImuTopicOpt = None,
    wheel_topic: WheelTopicOpt = None,
    point_time: PointTimeOpt = None,
    fmt: FormatOpt = None,
    as_json: JsonOpt = False,
    quiet: QuietOpt = False,
    force: ForceOpt = False,
) -> None:
    cfg = load_config(config)
    overrides = {"deskew": deskew, "prior": prior, "frame": frame, "planar": planar}
    data = cfg.model_dump()
    for key, value in overrides.items():
        if value is not None:
            data[key] = value
    if fusion is not None:
        data["fusion"]["method"] = fusion
    if alpha is not None:
        data["fusion"]["alpha"] = alpha
    if no_wheel:
        data["use_wheel"] = False
    if prior in ("constant-velocity", "none", "wheel") and deskew is None and cfg.deskew == "imu" and config is None:
        data["deskew"] = "constant-velocity" if prior != "none" else "none"
    from ..config import validate_config

    cfg = validate_config(data, "options")
    cal = load_calibration(calib) if calib else None
    conv = parse_time_convention(point_time) if point_time else None

    to_stdout = output == "-"
    if to_stdout and as_json:
        raise ConfigError("-o - and --json both write to stdout; choose one")
    out = None if to_stdout else Path(output) if output else Path(f"{_stem(log)}.tum")
    if out is not None:
        side = [out, _beside(out, ".metrics.json"), _beside(out, ".config.yaml")]
        for p in side:
            check_writable(p, force)

    with open_log(log, fmt) as reader:
        total = reader.topics.get(lidar_topic or "", None)
        with progress_bar("odometry", None if total is None else total.count, quiet) as advance:
            run = run_odometry(reader, cfg, lidar_topic=lidar_topic, imu_topic=imu_topic, wheel_topic=wheel_topic,
                               calib=cal, base_frame=base_frame, convention=conv, progress=advance)
    for n in run.notes:
        warn(n)
    tum = format_tum(run.stamps_ns, run.poses)
    m = run.metrics
    if gt is not None:
        m["accuracy"] = _score(log, gt, run)
    if to_stdout:
        sys.stdout.write(tum)
        sys.stdout.flush()
    else:
        m["output"] = str(out)
        with atomic_output(out, force) as tmp:
            tmp.write_text(tum)
        with atomic_output(_beside(out, ".config.yaml"), force) as tmp:
            tmp.write_text(dump_config(cfg))
        with atomic_output(_beside(out, ".metrics.json"), force) as tmp:
            tmp.write_text(json.dumps(m, indent=2) + "\n")
    sc = m["scans"]
    note(f"{sc['used']}/{sc['total']} scans used, {sc['degenerate']} degenerate, "
         f"{sc['registration_failures']} registration failures, {sc['imu_gaps']} IMU gaps; "
         f"{m['time_s']['total']:.1f} s wall, {m['real_time_factor'] or 0:.1f}x real time"
         + ("" if to_stdout else f"; wrote {out}"), quiet)
    note(f"start: {m['initialisation']}", quiet)
    if "accuracy" in m:
        a = m["accuracy"]
        rpe = "-" if a["rpe_trans_rmse_m"] is None else f"{a['rpe_trans_rmse_m']:.4f} m"
        err_console.print(f"against {a['reference']}: ATE {a['ate_trans_rmse_m']:.4f} m, {a['ate_rot_rmse_deg']:.3f} deg "
                          f"(SE(3)-aligned rmse over {a['matches']} poses); RPE over {a['rpe_delta']}: {rpe}", markup=False)
    if as_json:
        print_json(m)


def _score(log: Path, gt: str, run) -> dict:
    """ATE and RPE of the run against ground truth from a file or a topic of the log."""
    from ..evaluation import EvalOptions, Trajectory, evaluate
    from ..io.trajectory import load_trajectory

    spec = f"{log}:{gt}" if gt.startswith("/") and not Path(gt).exists() else gt
    ref = load_trajectory(spec)
    ref_traj = Trajectory(ref.stamps_ns, ref.poses, name=gt)
    est = Trajectory(run.stamps_ns, run.poses, name="odom")
    ate = evaluate(ref_traj, est, EvalOptions(max_diff_ns=20_000_000))
    length = ate.drift["path_length_m"] or 0.0
    delta, unit = (10.0, "m") if length >= 20.0 else (1.0, "s")
    rpe = evaluate(ref_traj, est, EvalOptions(max_diff_ns=20_000_000, delta=delta, delta_unit=unit))
    return {
        "reference": gt,
        "matches": len(ate.association.ref),
        "ate_trans_rmse_m": ate.stats["ape"]["trans"]["rmse"],
        "ate_rot_rmse_deg": ate.stats["ape"]["rot"]["rmse"],
        "rpe_delta": f"{delta:g} {unit}",
        "rpe_trans_rmse_m": rpe.stats["rpe"]["trans"]["rmse"] if len(rpe.rpe_pairs) else None,
        "final_error_m": ate.drift["final_error_m"],
        "alignment": "se3",
    }


def _stem(log: Path) -> str:
    p = Path(log)
    if p.name == "metadata.yaml":
        p = p.parent
    return p.name.removesuffix(".bag").removesuffix(".mcap") or "odom"


def _beside(out: Path, suffix: str) -> Path:
    name = out.name[: -len(out.suffix)] if out.suffix else out.name
    return out.with_name(name + suffix)


def register(app: typer.Typer) -> None:
    app.command("odom", help=HELP, no_args_is_help=True)(odom)
