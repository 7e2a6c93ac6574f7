"""``lio simulate``: write a synthetic log with exact ground truth."""

from __future__ import annotations

import time
from pathlib import Path
from typing import Annotated, Optional

import typer

from ..simulation import ALL_SCENARIOS, simulate
from ..simulation.options import parse_floats
from .common import ForceOpt, JsonOpt, QuietOpt, note, print_json, progress_bar

HELP = """Simulate a robot and its sensors in a synthetic world and write the log, with exact ground truth.

SCENARIO is one of:

  [bold]handheld[/bold]  a person walking indoors through rooms and doorways, fast yaw sweeps (> 3 rad/s), 16-beam LiDAR

  [bold]drive[/bold]     a car looping through a town at 5-10 m/s, 32-beam LiDAR (--beams 64/128), gentle roll/pitch

  [bold]corridor[/bold]  a robot in a long featureless corridor (LiDAR cannot see motion along it), wheel odometry

  [bold]planar[/bold]    a differential-drive robot in an office: 2D LaserScan, wheel encoders, IMU

  [bold]static[/bold]    an IMU at rest for hours (up to 48 h): white noise and bias random walks only, for Allan variance

OUT is x.bag (ROS 1), x.mcap (MCAP) or a folder x (ROS 2, sqlite3); --format overrides the guess. Beside it go x.gt.tum (pose of base in world, TUM), x.truth.json (true extrinsics, IMU biases and noise, clock offset, wheel radius/baseline errors, slip episode, start state, GPS georeference) and x.metrics.json (resolved options, topics, wall time).

Topics: /points or /scan (frame lidar, header stamp = sweep start unless --header-stamp end, recorded at sweep end), /imu (frame imu), /wheel/odom (odom -> base, not for handheld), /ground_truth (PoseStamped of base in world; --gt-type, --gt-topic), /tf_static (base -> imu, base -> lidar, base -> gps), /gps/fix with --gps. The platform stands still for the first 1.5 s unless --start moving. The same arguments and --seed give the same bytes.

Conditions of real recordings: --start moving (in motion at every sensor's first sample), --tilt-scale (more or less roll and pitch sway), --imu-rotation (any mounting, e.g. 180,0,90 upside down), --imu-time-offset and --imu-start-delay (IMU clock and driver start order), --header-stamp end, --gt-type odometry (nav_msgs/Odometry ground truth with zero twist), --no-tf-static (no extrinsics in the log), --no-wheel, --gps.

[bold]Examples[/bold]

  lio simulate handheld walk.bag --duration 30

  lio simulate drive town.mcap --beams 64 --time-convention ouster --seed 7

  lio simulate drive moving.bag --start moving --imu-rotation 0,0,30 --imu-time-offset -0.015 --gt-type odometry

  lio simulate handheld upside.mcap --start moving --imu-rotation 180,0,90 --imu-start-delay 0.15 --no-tf-static

  lio simulate corridor corridor_ros2 --format ros2 --imu-time-offset -0.005 --gps --gps-origin 47.37,8.54,408

  lio simulate static allan.mcap --duration 7200 --accel-noise 1.5e-3 --accel-walk 4e-4

  lio simulate planar office.mcap --noise-scale 0 --json   # ideal sensors
"""

_VEC = "comma-separated"


def simulate_cmd(
    scenario: Annotated[str, typer.Argument(help=f"One of: {', '.join(ALL_SCENARIOS)}.", show_default=False)],
    out: Annotated[Path, typer.Argument(help="Output log: x.bag, x.mcap or a ROS 2 folder.", show_default=False)],
    fmt: Annotated[Optional[str], typer.Option("--format", help="ros1, ros2 (sqlite3 folder), ros2-mcap or mcap (default: from OUT's suffix).", show_default=False)] = None,
    duration: Annotated[float, typer.Option("--duration", help="Seconds to simulate (including the 1.5 s at rest).")] = 20.0,
    seed: Annotated[int, typer.Option("--seed", help="Seed of every random draw (noise, biases, wheel errors).")] = 0,
    beams: Annotated[Optional[int], typer.Option("--beams", help="LiDAR beams: 16, 32, 64 or 128 (default 16; drive 32).", show_default=False)] = None,
    columns: Annotated[Optional[int], typer.Option("--columns", help="LiDAR columns per revolution (default 1024; planar: LaserScan beams, default 720).", show_default=False)] = None,
    imu_rate: Annotated[float, typer.Option("--imu-rate", help="IMU rate in Hz.")] = 200.0,
    time_convention: Annotated[str, typer.Option("--time-convention", help="Per-point time field: velodyne (time, s), ouster (t, ns), livox (offset_time, ns), hesai (timestamp, absolute s).")] = "velodyne",
    header_stamp: Annotated[str, typer.Option("--header-stamp", help="What a cloud's header stamp marks: start or end of the sweep (end: relative times <= 0; velodyne or hesai only).")] = "start",
    imu_time_offset: Annotated[float, typer.Option("--imu-time-offset", help="Seconds added to IMU stamps to put them on the LiDAR's clock (as imu_time_offset_s of a calibration): IMU stamp = true time - offset.")] = 0.0,
    noise_scale: Annotated[float, typer.Option("--noise-scale", help="Multiplies every sensor noise, bias and walk; 0 gives ideal sensors (and no wheel errors).")] = 1.0,
    range_noise: Annotated[Optional[float], typer.Option("--range-noise", help="LiDAR range noise std in m (default 0.015; planar 0.01).", show_default=False)] = None,
    dropout: Annotated[Optional[float], typer.Option("--dropout", help="Fraction of LiDAR returns lost (default 0.01).", show_default=False)] = None,
    max_range: Annotated[Optional[float], typer.Option("--max-range", help="LiDAR maximum range in m (default 100; drive 120; planar 30).", show_default=False)] = None,
    accel_noise: Annotated[Optional[float], typer.Option("--accel-noise", help="Accelerometer noise density, m/s^2/sqrt(Hz) (default 2e-3).", show_default=False)] = None,
    gyro_noise: Annotated[Optional[float], typer.Option("--gyro-noise", help="Gyroscope noise density, rad/s/sqrt(Hz) (default 1.7e-4).", show_default=False)] = None,
    accel_walk: Annotated[Optional[float], typer.Option("--accel-walk", help="Accelerometer bias random walk, m/s^3/sqrt(Hz) (default 3e-4).", show_default=False)] = None,
    gyro_walk: Annotated[Optional[float], typer.Option("--gyro-walk", help="Gyroscope bias random walk, rad/s^2/sqrt(Hz) (default 2e-5).", show_default=False)] = None,
    accel_bias: Annotated[Optional[str], typer.Option("--accel-bias", metavar="X,Y,Z", help="Initial accelerometer bias in m/s^2 (default: drawn from --seed; not scaled by --noise-scale).", show_default=False)] = None,
    gyro_bias: Annotated[Optional[str], typer.Option("--gyro-bias", metavar="X,Y,Z", help="Initial gyroscope bias in rad/s (default: drawn from --seed; not scaled).", show_default=False)] = None,
    wheel_errors: Annotated[bool, typer.Option("--wheel-errors/--no-wheel-errors", help="Wheel radius/baseline errors and a slip episode.")] = True,
    wheel_radius_scale: Annotated[Optional[str], typer.Option("--wheel-radius-scale", metavar="LEFT,RIGHT", help="True wheel radius / nominal, each wheel (default: drawn; applies even with --no-wheel-errors).", show_default=False)] = None,
    wheel_baseline_scale: Annotated[Optional[float], typer.Option("--wheel-baseline-scale", help="True baseline / nominal (default: drawn).", show_default=False)] = None,
    start: Annotated[str, typer.Option("--start", help="still: at rest for 1.5 s, then off; moving: in motion at every sensor's first sample (drive: cruising at 7.5 m/s so the IMU looks still; handheld: walking with full yaw sweeps); accelerating: half-way up its speed ramp at the first sample (drive: 3.75 m/s, 3.75 m/s^2).")] = "still",
    tilt_scale: Annotated[float, typer.Option("--tilt-scale", help="Scale the platform's roll and pitch sway (0..5; 0: level; handheld 3: the tilting lio calibrate asks for to see the vertical lever arm, pitch +-14 deg).")] = 1.0,
    imu_rotation: Annotated[Optional[str], typer.Option("--imu-rotation", metavar="ROLL,PITCH,YAW", help="IMU mounting rotation in degrees, R_base_imu = Rz(yaw) Ry(pitch) Rx(roll); 180,0,90 is upside down and yawed (default: the scenario's).", show_default=False)] = None,
    imu_lever_arm: Annotated[Optional[str], typer.Option("--imu-lever-arm", metavar="X,Y,Z", help="IMU origin in base, metres (default: the scenario's).", show_default=False)] = None,
    imu_start_delay: Annotated[float, typer.Option("--imu-start-delay", help="The IMU driver starts this many seconds after the first scan (> 0.1 s: the first scan is also recorded before the first IMU message).")] = 0.0,
    gt_type: Annotated[Optional[str], typer.Option("--gt-type", help="Ground truth topic type: pose (PoseStamped), odometry (nav_msgs/Odometry, twist all zero unless --gt-twist) or none (default: pose; static: none).", show_default=False)] = None,
    gt_topic: Annotated[str, typer.Option("--gt-topic", help="Ground truth topic name.")] = "/ground_truth",
    gt_twist: Annotated[bool, typer.Option("--gt-twist", help="Fill the Odometry ground truth's twist with the true velocities (base frame).")] = False,
    tf_static: Annotated[bool, typer.Option("--tf-static/--no-tf-static", help="Write the extrinsics on /tf_static (--no-tf-static: tools need --calib).")] = True,
    wheel: Annotated[Optional[bool], typer.Option("--wheel/--no-wheel", help="Wheel odometry on /wheel/odom (default: drive, corridor and planar have it).", show_default=False)] = None,
    gps: Annotated[bool, typer.Option("--gps", help="Add a GPS receiver: sensor_msgs/NavSatFix on /gps/fix, with invalid fixes and an outage.")] = False,
    gps_rate: Annotated[Optional[float], typer.Option("--gps-rate", help="GPS rate in Hz (default 5; implies --gps).", show_default=False)] = None,
    gps_origin: Annotated[Optional[str], typer.Option("--gps-origin", metavar="LAT,LON,ALT", help="Geodetic position of the world origin: degrees, degrees, WGS84 ellipsoidal height m (default 48.137154,11.576124,519; implies --gps).", show_default=False)] = None,
    gps_noise: Annotated[Optional[str], typer.Option("--gps-noise", metavar="HORIZONTAL,VERTICAL", help="GPS error 1-sigma in m: east and north each, up (default 1,2; implies --gps).", show_default=False)] = None,
    gps_outage: Annotated[Optional[float], typer.Option("--gps-outage", help="Seconds without any GPS message, from 55% of the run (default: min(10, 10% of the run); 0: none; implies --gps).", show_default=False)] = None,
    gps_invalid: Annotated[Optional[float], typer.Option("--gps-invalid", help="Share of GPS fixes without a solution, status -1 (default 0.02; implies --gps).", show_default=False)] = None,
    force: ForceOpt = False,
    as_json: JsonOpt = False,
    quiet: QuietOpt = False,
) -> None:
    gps_opts: dict = {}
    if gps_rate is not None:
        gps_opts["gps_rate_hz"] = gps_rate
    if gps_origin is not None:
        gps_opts["gps_origin"] = parse_floats(gps_origin, 3, "--gps-origin")
    if gps_noise is not None:
        gps_opts["gps_noise_m"] = parse_floats(gps_noise, 2, "--gps-noise")
    if gps_outage is not None:
        gps_opts["gps_outage_s"] = gps_outage
    if gps_invalid is not None:
        gps_opts["gps_invalid_fraction"] = gps_invalid
    t0 = time.perf_counter()
    with progress_bar(f"simulating {scenario}", duration, quiet) as advance:
        res = simulate(
            scenario, out, fmt, duration_s=duration, seed=seed, force=force, progress=advance, beams=beams,
            columns=columns, imu_rate_hz=imu_rate, time_convention=time_convention, header_stamp=header_stamp,
            imu_time_offset_s=imu_time_offset,
            noise_scale=noise_scale, range_noise_m=range_noise, dropout=dropout, max_range_m=max_range,
            accel_noise_density=accel_noise, gyro_noise_density=gyro_noise, wheel_errors=wheel_errors,
            accel_bias_walk=accel_walk, gyro_bias_walk=gyro_walk,
            accel_bias_mps2=parse_floats(accel_bias, 3, "--accel-bias"),
            gyro_bias_radps=parse_floats(gyro_bias, 3, "--gyro-bias"),
            wheel_radius_scale=parse_floats(wheel_radius_scale, 2, "--wheel-radius-scale"),
            wheel_baseline_scale=wheel_baseline_scale, start=start, tilt_scale=tilt_scale,
            imu_rotation_deg=parse_floats(imu_rotation, 3, "--imu-rotation"),
            imu_lever_arm_m=parse_floats(imu_lever_arm, 3, "--imu-lever-arm"), imu_start_delay_s=imu_start_delay,
            gt_type=gt_type, gt_topic=gt_topic, gt_twist=gt_twist, tf_static=tf_static, wheel=wheel,
            gps=gps or bool(gps_opts), **gps_opts,
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
        note(f"  ground truth {res.gt_path}, true parameters {res.truth_path}, metrics {res.metrics_path}", quiet)


def register(app: typer.Typer) -> None:
    app.command("simulate", help=HELP, no_args_is_help=True)(simulate_cmd)
