"""``lio simulate``: write a synthetic log with exact ground truth."""

from __future__ import annotations

import time
from pathlib import Path
from typing import Annotated, Literal, Optional

import typer

from ..simulation import ALL_SCENARIOS, FORMATS, STARTS, TIME_CONVENTIONS, simulate
from ..simulation.options import GPS_COVARIANCES, GPS_MODELS, GT_TYPES, parse_floats
from ..simulation.stops import RAMP_S, parse_stop
from ..simulation.terrain import parse_hills
from .common import (CALIBRATION_PANEL, FLAG, MOTION_PANEL, OUTPUT_PANEL, RUN_PANEL, ForceOpt, JsonOpt, LioCommand,
                     QuietOpt, note, one_of, print_json, progress_bar, shown)

HELP = """Simulate a robot and its sensors in a synthetic world and write the log, with exact ground truth.

SCENARIO is one of:

  [bold]handheld[/bold]  walking indoors, fast yaw sweeps (> 3 rad/s), 16-beam LiDAR
  [bold]drive[/bold]     a car looping through a town at 5-10 m/s, 32-beam LiDAR
  [bold]corridor[/bold]  a long featureless corridor, wheel odometry
  [bold]planar[/bold]    a differential-drive robot: 2D LaserScan, wheels, IMU
  [bold]rover[/bold]     a ground robot on uneven roads outdoors: 16-beam LiDAR, wheels
  [bold]drone[/bold]     a multicopter over a town, climbing and sinking: 16-beam LiDAR
  [bold]static[/bold]    an IMU at rest for up to 48 h, for Allan variance

OUT is x.bag (ROS 1), x.mcap (MCAP) or a folder x (ROS 2, sqlite3); --format overrides the guess. Beside it go
x.gt.tum (pose of base in world), x.truth.json (true extrinsics, IMU biases and noise, clock offset, wheel
errors, GPS georeference) and x.sim.metrics.json (resolved options, topics, wall time).

Topics: /points or /scan (frame lidar), /imu, /wheel/odom (not handheld, drone), /ground_truth, /tf_static
(base -> imu, lidar, gps), /gps/fix with --gps. The platform stands still for the first 1.5 s unless
--start moving, and mid-log where --stop says. The same arguments and --seed give the same bytes. The
conditions of real recordings (moving start, any IMU mounting, clock offsets, no /tf_static...) are described
in docs/commands/simulate.md.

The error model has options of its own, left out below and described there: --range-noise, --dropout,
--max-range, --accel-noise, --gyro-noise, --accel-walk, --gyro-walk, --accel-bias, --gyro-bias,
--no-wheel-errors, --wheel-radius-scale, --wheel-baseline-scale, --wheel-slip-bursts, --gps-rate,
--gps-origin, --gps-noise, --gps-outage, --gps-invalid, --gps-model (consumer: metres of slow error, altitude
wander, a multipath jump, optimistic covariance), --gps-alt-wander, --gps-jump and --gps-covariance.

[bold]Examples[/bold]

  lio simulate handheld walk.bag --duration 30
  lio simulate drive town.mcap --beams 64 --time-convention ouster --seed 7
  lio simulate drive moving.bag --start moving --imu-rotation 0,0,30
  lio simulate handheld upside.mcap --imu-rotation 180,0,90 --no-tf-static
  lio simulate corridor corridor_ros2 --format ros2 --gps
  lio simulate rover field.mcap --start moving --gps-model consumer
  lio simulate drive lights.mcap --duration 45 --stop 20:5 --stop 37:10
  lio simulate rover hills.mcap --no-lidar --hills 2:150 --gps
  lio simulate static allan.mcap --duration 7200
  lio simulate planar office.mcap --noise-scale 0 --json   # ideal sensors
"""

SENSORS_PANEL = "Sensors"
Scenario = Literal[ALL_SCENARIOS]
OutFormat = Literal[FORMATS]
TimeConvention = Literal[TIME_CONVENTIONS]
HeaderStamp = Literal["start", "end"]
Start = Literal[STARTS]
GtType = Literal[GT_TYPES]
GpsModel = Literal[GPS_MODELS]
GpsCovariance = Literal[GPS_COVARIANCES]


def simulate_cmd(
    scenario: Annotated[Scenario, typer.Argument(metavar="SCENARIO", show_choices=False, help=f"One of: {', '.join(ALL_SCENARIOS)}.", show_default=False)],
    out: Annotated[Path, typer.Argument(metavar="OUT", help="Output log: x.bag, x.mcap or a ROS 2 folder.", show_default=False)],
    start: Annotated[Start, typer.Option("--start", metavar=one_of(Start), help="still: at rest for 1.5 s; moving: in motion at every sensor's first sample; accelerating: half-way up its speed ramp (drive).", rich_help_panel=MOTION_PANEL)] = "still",
    tilt_scale: Annotated[float, typer.Option("--tilt-scale", help="Scale of the roll and pitch sway (0..5; 0: level).", rich_help_panel=MOTION_PANEL)] = 1.0,
    hills: Annotated[Optional[str], typer.Option("--hills", metavar="AMPLITUDE:WAVELENGTH", help="Ground height AMPLITUDE sin(2 pi s / WAVELENGTH) along the path, m; the base pitches with the grade (needs --no-lidar).", show_default=False, rich_help_panel=MOTION_PANEL)] = None,
    stop: Annotated[Optional[list[str]], typer.Option("--stop", metavar="AT:SECONDS", help=f"Stand exactly still for SECONDS from AT (seconds since the start), braking over the {RAMP_S:g} s before AT and driving off over the {RAMP_S:g} s after (repeat); may run past the end: the log ends parked.", show_default=False, rich_help_panel=MOTION_PANEL)] = None,
    beams: Annotated[Optional[int], typer.Option("--beams", help=shown("LiDAR beams: 16, 32, 64 or 128.", "16; drive 32"), show_default=False, rich_help_panel=SENSORS_PANEL)] = None,
    columns: Annotated[Optional[int], typer.Option("--columns", help=shown("LiDAR columns per turn (planar: LaserScan beams).", "1024; planar 720"), show_default=False, rich_help_panel=SENSORS_PANEL)] = None,
    imu_rate: Annotated[float, typer.Option("--imu-rate", help="IMU rate in Hz.", rich_help_panel=SENSORS_PANEL)] = 200.0,
    time_convention: Annotated[TimeConvention, typer.Option("--time-convention", metavar=one_of(TimeConvention), help="Per-point time field as the driver writes it.", rich_help_panel=SENSORS_PANEL)] = "velodyne",
    header_stamp: Annotated[HeaderStamp, typer.Option("--header-stamp", metavar=one_of(HeaderStamp), help="What a cloud's header stamp marks (end: velodyne or hesai).", rich_help_panel=SENSORS_PANEL)] = "start",
    noise_scale: Annotated[float, typer.Option("--noise-scale", help="Multiplies every noise, bias and walk; 0: ideal sensors.", rich_help_panel=SENSORS_PANEL)] = 1.0,
    range_noise: Annotated[Optional[float], typer.Option("--range-noise", hidden=True, help=shown("LiDAR range noise std, m.", "0.015; planar 0.01"), show_default=False, rich_help_panel=SENSORS_PANEL)] = None,
    dropout: Annotated[Optional[float], typer.Option("--dropout", hidden=True, help=shown("Share of LiDAR returns lost.", 0.01), show_default=False, rich_help_panel=SENSORS_PANEL)] = None,
    max_range: Annotated[Optional[float], typer.Option("--max-range", hidden=True, help=shown("LiDAR maximum range, m.", "100; drive 120; planar 30"), show_default=False, rich_help_panel=SENSORS_PANEL)] = None,
    accel_noise: Annotated[Optional[float], typer.Option("--accel-noise", hidden=True, help=shown("Accelerometer noise density, m/s^2/sqrt(Hz).", "2e-3"), show_default=False, rich_help_panel=SENSORS_PANEL)] = None,
    gyro_noise: Annotated[Optional[float], typer.Option("--gyro-noise", hidden=True, help=shown("Gyroscope noise density, rad/s/sqrt(Hz).", "1.7e-4"), show_default=False, rich_help_panel=SENSORS_PANEL)] = None,
    accel_walk: Annotated[Optional[float], typer.Option("--accel-walk", hidden=True, help=shown("Accelerometer bias walk, m/s^3/sqrt(Hz).", "3e-4"), show_default=False, rich_help_panel=SENSORS_PANEL)] = None,
    gyro_walk: Annotated[Optional[float], typer.Option("--gyro-walk", hidden=True, help=shown("Gyroscope bias walk, rad/s^2/sqrt(Hz).", "2e-5"), show_default=False, rich_help_panel=SENSORS_PANEL)] = None,
    accel_bias: Annotated[Optional[str], typer.Option("--accel-bias", hidden=True, metavar="X,Y,Z", help=shown("Initial accelerometer bias, m/s^2 (not scaled by --noise-scale).", "drawn"), show_default=False, rich_help_panel=SENSORS_PANEL)] = None,
    gyro_bias: Annotated[Optional[str], typer.Option("--gyro-bias", hidden=True, metavar="X,Y,Z", help=shown("Initial gyroscope bias, rad/s (not scaled).", "drawn"), show_default=False, rich_help_panel=SENSORS_PANEL)] = None,
    wheel_errors: Annotated[bool, typer.Option("--wheel-errors/--no-wheel-errors", hidden=True, metavar=FLAG, help="Wheel radius and baseline errors and a slip episode.", rich_help_panel=SENSORS_PANEL)] = True,
    imu_rotation: Annotated[Optional[str], typer.Option("--imu-rotation", metavar="R,P,Y", help=shown("IMU mounting in degrees, R_base_imu = Rz(Y) Ry(P) Rx(R); 180,0,90: upside down, yawed.", "the scenario's"), show_default=False, rich_help_panel=CALIBRATION_PANEL)] = None,
    imu_lever_arm: Annotated[Optional[str], typer.Option("--imu-lever-arm", metavar="X,Y,Z", help=shown("IMU origin in base, m.", "the scenario's"), show_default=False, rich_help_panel=CALIBRATION_PANEL)] = None,
    imu_time_offset: Annotated[float, typer.Option("--imu-time-offset", help="Seconds added to IMU stamps to put them on the LiDAR's clock: IMU stamp = true time - offset.", rich_help_panel=CALIBRATION_PANEL)] = 0.0,
    imu_start_delay: Annotated[float, typer.Option("--imu-start-delay", help="The IMU starts this many seconds after the first scan.", rich_help_panel=CALIBRATION_PANEL)] = 0.0,
    wheel_radius_scale: Annotated[Optional[str], typer.Option("--wheel-radius-scale", hidden=True, metavar="L,R", help=shown("True wheel radius / nominal, each wheel.", "drawn"), show_default=False, rich_help_panel=CALIBRATION_PANEL)] = None,
    wheel_baseline_scale: Annotated[Optional[float], typer.Option("--wheel-baseline-scale", hidden=True, help=shown("True baseline / nominal.", "drawn"), show_default=False, rich_help_panel=CALIBRATION_PANEL)] = None,
    wheel_slip_bursts: Annotated[int, typer.Option("--wheel-slip-bursts", hidden=True, help="Slip bursts of 1-2.5 s (each wheel 10-40 %) spread over the run.")] = 0,
    gps: Annotated[bool, typer.Option("--gps", metavar=FLAG, help="A GPS receiver on /gps/fix (NavSatFix), with invalid fixes and an outage.", rich_help_panel=SENSORS_PANEL)] = False,
    gps_rate: Annotated[Optional[float], typer.Option("--gps-rate", hidden=True, help=shown("GPS rate in Hz; implies --gps.", 5), show_default=False)] = None,
    gps_origin: Annotated[Optional[str], typer.Option("--gps-origin", hidden=True, metavar="LAT,LON,ALT", help=shown("World origin: deg, deg, m above the WGS84 ellipsoid.", "48.137154,11.576124,519"), show_default=False)] = None,
    gps_noise: Annotated[Optional[str], typer.Option("--gps-noise", hidden=True, metavar="H,V", help=shown("GPS 1-sigma, m: east and north each, up.", "1,2"), show_default=False)] = None,
    gps_outage: Annotated[Optional[float], typer.Option("--gps-outage", hidden=True, help=shown("Seconds without GPS from 55% of the run; 0: none.", "min(10, 10% of the run)"), show_default=False)] = None,
    gps_invalid: Annotated[Optional[float], typer.Option("--gps-invalid", hidden=True, help=shown("Share of fixes without a solution.", 0.02), show_default=False)] = None,
    gps_model: Annotated[Optional[GpsModel], typer.Option("--gps-model", hidden=True, metavar=one_of(GpsModel), help=shown("Receiver error model; implies --gps.", "standard"), show_default=False)] = None,
    gps_alt_wander: Annotated[Optional[float], typer.Option("--gps-alt-wander", hidden=True, help=shown("Slow altitude wander, m peak to peak; implies --gps.", "standard 0, consumer 25"), show_default=False)] = None,
    gps_jump: Annotated[Optional[float], typer.Option("--gps-jump", hidden=True, help=shown("Multipath jump, m, for min(5 s, 10% of the run) from 30% of it; implies --gps.", "standard 0, consumer 8"), show_default=False)] = None,
    gps_covariance: Annotated[Optional[GpsCovariance], typer.Option("--gps-covariance", hidden=True, metavar=one_of(GpsCovariance), help=shown("What the fixes report; implies --gps.", "standard true, consumer optimistic"), show_default=False)] = None,
    lidar: Annotated[bool, typer.Option("--lidar/--no-lidar", metavar=FLAG, help="The LiDAR topic (without: a log for IMU, wheel and GPS work, written in seconds).", rich_help_panel=OUTPUT_PANEL)] = True,
    fmt: Annotated[Optional[OutFormat], typer.Option("--format", metavar=one_of(OutFormat), help=shown("Output format (ros2: sqlite3 folder).", "from OUT's suffix"), show_default=False, rich_help_panel=OUTPUT_PANEL)] = None,
    gt_type: Annotated[Optional[GtType], typer.Option("--gt-type", metavar=one_of(GtType), help=shown("Ground truth topic: PoseStamped, nav_msgs/Odometry (zero twist unless --gt-twist) or none.", "pose; static none"), show_default=False, rich_help_panel=OUTPUT_PANEL)] = None,
    gt_topic: Annotated[str, typer.Option("--gt-topic", help="Ground truth topic name.", rich_help_panel=OUTPUT_PANEL)] = "/ground_truth",
    gt_twist: Annotated[bool, typer.Option("--gt-twist", metavar=FLAG, help="Fill the Odometry ground truth's twist.", rich_help_panel=OUTPUT_PANEL)] = False,
    tf_static: Annotated[bool, typer.Option("--tf-static/--no-tf-static", metavar=FLAG, help="Extrinsics on /tf_static (without: tools need --calib).", rich_help_panel=OUTPUT_PANEL)] = True,
    wheel: Annotated[Optional[bool], typer.Option("--wheel/--no-wheel", metavar=FLAG, help=shown("Wheel odometry on /wheel/odom.", "drive, corridor, planar"), show_default=False, rich_help_panel=OUTPUT_PANEL)] = None,
    as_json: JsonOpt = False,
    force: ForceOpt = False,
    duration: Annotated[float, typer.Option("--duration", help="Seconds to simulate, the 1.5 s at rest included.", rich_help_panel=RUN_PANEL)] = 20.0,
    seed: Annotated[int, typer.Option("--seed", help="Seed of every random draw.", rich_help_panel=RUN_PANEL)] = 0,
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
    for key, value in (("gps_model", gps_model), ("gps_alt_wander_m", gps_alt_wander), ("gps_jump_m", gps_jump),
                       ("gps_covariance", gps_covariance)):
        if value is not None:
            gps_opts[key] = value
    stops = tuple(parse_stop(text) for text in stop or ())
    terrain = None if hills is None else parse_hills(hills)
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
            gps=gps or bool(gps_opts), wheel_slip_bursts=wheel_slip_bursts, lidar=lidar, stops=stops,
            hills=terrain, **gps_opts,
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
    app.command("simulate", help=HELP, no_args_is_help=True, cls=LioCommand)(simulate_cmd)
