"""``lio simulate``: write a synthetic log with exact ground truth."""

from __future__ import annotations

import time
from pathlib import Path
from typing import Annotated, Optional

import typer

from ..simulation import SCENARIOS, simulate
from .common import ForceOpt, JsonOpt, QuietOpt, note, print_json, progress_bar

HELP = """Simulate a robot and its sensors in a synthetic world and write the log, with exact ground truth.

SCENARIO is one of:

  [bold]handheld[/bold]  a person walking indoors through rooms and doorways, fast yaw sweeps (> 3 rad/s), 16-beam LiDAR

  [bold]drive[/bold]     a car looping through a town at 5-10 m/s, 32-beam LiDAR (--beams 64/128), gentle roll/pitch

  [bold]corridor[/bold]  a robot in a long featureless corridor (LiDAR cannot see motion along it), wheel odometry

  [bold]planar[/bold]    a differential-drive robot in an office: 2D LaserScan, wheel encoders, IMU

OUT is x.bag (ROS 1), x.mcap (MCAP) or a folder x (ROS 2, sqlite3); --format overrides the guess. Beside it go x.gt.tum (pose of base in world, TUM) and x.truth.json (true extrinsics, IMU biases, clock offset, wheel radius/baseline errors, slip episode).

Topics: /points or /scan (frame lidar, header stamp = sweep start unless --header-stamp end, recorded at sweep end), /imu (frame imu), /wheel/odom (odom -> base, not for handheld), /ground_truth (PoseStamped of base in world), /tf_static (base -> imu, base -> lidar). The platform stands still for the first 1.5 s. The same arguments and --seed give the same bytes.

[bold]Examples[/bold]

  lio simulate handheld walk.bag --duration 30

  lio simulate drive town.mcap --beams 64 --time-convention ouster --seed 7

  lio simulate corridor corridor_ros2 --format ros2 --imu-time-offset 0.005

  lio simulate planar office.mcap --noise-scale 0 --json   # ideal sensors
"""


def simulate_cmd(
    scenario: Annotated[str, typer.Argument(help=f"One of: {', '.join(SCENARIOS)}.", show_default=False)],
    out: Annotated[Path, typer.Argument(help="Output log: x.bag, x.mcap or a ROS 2 folder.", show_default=False)],
    fmt: Annotated[Optional[str], typer.Option("--format", help="ros1, ros2 (sqlite3 folder), ros2-mcap or mcap (default: from OUT's suffix).", show_default=False)] = None,
    duration: Annotated[float, typer.Option("--duration", help="Seconds to simulate (including the 1.5 s at rest).")] = 20.0,
    seed: Annotated[int, typer.Option("--seed", help="Seed of every random draw (noise, biases, wheel errors).")] = 0,
    beams: Annotated[Optional[int], typer.Option("--beams", help="LiDAR beams: 16, 32, 64 or 128 (default 16; drive 32).", show_default=False)] = None,
    columns: Annotated[Optional[int], typer.Option("--columns", help="LiDAR columns per revolution (default 1024; planar: LaserScan beams, default 720).", show_default=False)] = None,
    imu_rate: Annotated[float, typer.Option("--imu-rate", help="IMU rate in Hz.")] = 200.0,
    time_convention: Annotated[str, typer.Option("--time-convention", help="Per-point time field: velodyne (time, s), ouster (t, ns), livox (offset_time, ns), hesai (timestamp, absolute s).")] = "velodyne",
    header_stamp: Annotated[str, typer.Option("--header-stamp", help="What a cloud's header stamp marks: start or end of the sweep (end: relative times <= 0; velodyne or hesai only).")] = "start",
    imu_time_offset: Annotated[float, typer.Option("--imu-time-offset", help="IMU clock offset in s: IMU stamp = true time + offset.")] = 0.0,
    noise_scale: Annotated[float, typer.Option("--noise-scale", help="Multiplies every sensor noise, bias and walk; 0 gives ideal sensors (and no wheel errors).")] = 1.0,
    range_noise: Annotated[Optional[float], typer.Option("--range-noise", help="LiDAR range noise std in m (default 0.015; planar 0.01).", show_default=False)] = None,
    dropout: Annotated[Optional[float], typer.Option("--dropout", help="Fraction of LiDAR returns lost (default 0.01).", show_default=False)] = None,
    max_range: Annotated[Optional[float], typer.Option("--max-range", help="LiDAR maximum range in m (default 100; drive 120; planar 30).", show_default=False)] = None,
    accel_noise: Annotated[Optional[float], typer.Option("--accel-noise", help="Accelerometer noise density, m/s^2/sqrt(Hz) (default 2e-3).", show_default=False)] = None,
    gyro_noise: Annotated[Optional[float], typer.Option("--gyro-noise", help="Gyroscope noise density, rad/s/sqrt(Hz) (default 1.7e-4).", show_default=False)] = None,
    wheel_errors: Annotated[bool, typer.Option("--wheel-errors/--no-wheel-errors", help="Wheel radius/baseline errors and a slip episode.")] = True,
    force: ForceOpt = False,
    as_json: JsonOpt = False,
    quiet: QuietOpt = False,
) -> None:
    t0 = time.perf_counter()
    with progress_bar(f"simulating {scenario}", duration, quiet) as advance:
        res = simulate(
            scenario, out, fmt, duration_s=duration, seed=seed, force=force, progress=advance, beams=beams,
            columns=columns, imu_rate_hz=imu_rate, time_convention=time_convention, header_stamp=header_stamp,
            imu_time_offset_s=imu_time_offset,
            noise_scale=noise_scale, range_noise_m=range_noise, dropout=dropout, max_range_m=max_range,
            accel_noise_density=accel_noise, gyro_noise_density=gyro_noise, wheel_errors=wheel_errors,
        )
    wall = time.perf_counter() - t0
    summary = res.to_dict()
    summary["wall_s"] = round(wall, 3)
    summary["realtime_factor"] = round(duration / wall, 3) if wall > 0 else None
    if as_json:
        print_json(summary)
        return
    if not quiet:
        topics = ", ".join(f"{t} {v['count']}" for t, v in res.topics.items())
        note(f"wrote {res.log_path} ({res.format}): {duration:g} s of {scenario} simulated in {wall:.1f} s "
             f"({duration / wall:.1f}x real time)", quiet)
        note(f"  {topics}", quiet)
        note(f"  ground truth {res.gt_path}, true parameters {res.truth_path}", quiet)


def register(app: typer.Typer) -> None:
    app.command("simulate", help=HELP, no_args_is_help=True)(simulate_cmd)
