"""``lio odom``: IMU-primed scan matching over a log (flags -> OdomJob -> run_odom -> score_odom -> write_odom ->
print)."""

# no ``from __future__ import annotations``: typer then reads the flags' annotations as objects instead of
# compiling each string at every start (4 ms)
import math
import sys
from pathlib import Path
from typing import Annotated, Literal, Optional

import typer

from ..config import load_config, with_overrides
from ..config.odom import OdomConfig
from ..errors import ConfigError
from ..io.logs.detect import input_paths
from ..io.messages.pointcloud import parse_time_convention
from ..io.files.trajectory import format_tum
from ..io.files.atomic import check_writable
from ..io.files.output_paths import check_plot_dir, plot_outputs, refuse_shared_outputs, refuse_stdout
from ..io.files.point_clouds import check_map_suffix
from ..jobs.contract import load_reference
from ..jobs.odom import (TAG, DivergedRun, OdomJob, OdomResult, map_outputs, run_odom, score_odom, write_odom,
                         write_odom_map, write_odom_plots)
from ..jobs.outputs import check_outputs, default_output, log_stem, run_outputs
from .common import (FLAG, INPUT_PANEL, MOTION_PANEL, OUTPUT_PANEL, BaseFrameOpt, CalibOpt, ConfigOpt, ForceOpt,
                     FormatOpt, ImuTimeOffsetOpt, ImuTopicOpt, JsonOpt, LidarTopicOpt, LioCommand, LogArg, PointTimeOpt,
                     PreferCalibOpt, QuietOpt, WheelTopicOpt, config_default, err_console, job_progress, note, one_of,
                     plural, prefer_calib_override, print_json, shown, warn)

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
With -o - the trajectory goes to stdout and no other file is written unless asked for:

--map FILE.ply|.pcd: the map of the run, every de-skewed scan at its pose, voxel-downsampled (--map-voxel),
in the trajectory's world frame; FILE-stem.png beside it shows it from above with the trajectory.

--plot DIR: the pictures of lio plot (top view, x/y/z, roll/pitch/yaw, speed) of the trajectory, with the
ground truth of --gt drawn under it (the odometry aligned to it as the score is).

--viz shows the run in rerun's viewer as it goes (each scan at its pose, the trajectory, at the end the
map); --viz-save FILE.rrd records the same (rerun FILE.rrd shows it). Both need pip install 'lio-cli\\[viz]'.

[bold]Examples[/bold]

  lio odom sample_logs/handheld.bag   # writes handheld.odom.tum
  lio odom run.mcap --lidar-topic /os/points -o - | head
  lio odom run.mcap --fusion complementary --alpha 0.9 -o run.tum
  lio odom corridor_ros2/ --prior wheel --json > metrics.json
  lio odom scan2d.bag --prior constant-velocity   # LiDAR only
  lio odom walk.bag --map walk.ply --plot walk_plots/
"""


Prior = Literal["imu", "constant-velocity", "wheel", "none"]
Deskew = Literal["auto", "imu", "constant-velocity", "none"]
Fusion = Literal["ekf", "complementary"]
Frame = Literal["base", "lidar", "imu"]


def _default(field: str):
    return config_default(OdomConfig, field)


def odom(
    log: LogArg,
    fmt: FormatOpt = None,
    lidar_topic: LidarTopicOpt = None,
    imu_topic: ImuTopicOpt = None,
    wheel_topic: WheelTopicOpt = None,
    no_wheel: Annotated[bool, typer.Option("--no-wheel", metavar=FLAG, help="Ignore wheel odometry even if the log has it.", rich_help_panel=INPUT_PANEL)] = False,
    point_time: PointTimeOpt = None,
    base_frame: BaseFrameOpt = None,
    gt: Annotated[Optional[str], typer.Option("--gt", help="Ground truth to score against at the end: a TUM/KITTI file or a topic of LOG (e.g. /ground_truth); prints ATE and RPE.", show_default=False, rich_help_panel=INPUT_PANEL)] = None,
    prior: Annotated[Optional[Prior], typer.Option("--prior", metavar=one_of(Prior), help=shown("Initial guess of each registration.", _default("prior")), show_default=False, rich_help_panel=MOTION_PANEL)] = None,
    deskew: Annotated[Optional[Deskew], typer.Option("--deskew", metavar=one_of(Deskew), help=shown("De-skewing; auto: imu with the IMU prior, none with none, else constant-velocity.", _default("deskew")), show_default=False, rich_help_panel=MOTION_PANEL)] = None,
    fusion: Annotated[Optional[Fusion], typer.Option("--fusion", metavar=one_of(Fusion), help=shown("How the scan match corrects the IMU state.", _default("fusion.method")), show_default=False, rich_help_panel=MOTION_PANEL)] = None,
    alpha: Annotated[Optional[float], typer.Option("--alpha", min=0, max=1, metavar="<float>", help=shown("Complementary filter's weight of the scan match.", _default("fusion.alpha")), show_default=False, rich_help_panel=MOTION_PANEL)] = None,
    planar: Annotated[Optional[bool], typer.Option("--planar/--no-planar", metavar=FLAG, help=shown("SE(2) mode.", "on for LaserScan"), show_default=False, rich_help_panel=MOTION_PANEL)] = None,
    calib: CalibOpt = None,
    prefer_calib: PreferCalibOpt = False,
    imu_time_offset: ImuTimeOffsetOpt = None,
    output: Annotated[Optional[str], typer.Option("-o", "--output", help=shown("TUM trajectory file, or - for stdout.", "LOG-stem.odom.tum"), show_default=False, rich_help_panel=OUTPUT_PANEL)] = None,
    frame: Annotated[Optional[Frame], typer.Option("--frame", metavar=one_of(Frame), help=shown("Whose trajectory is written.", _default("frame")), show_default=False, rich_help_panel=OUTPUT_PANEL)] = None,
    map_file: Annotated[Optional[Path], typer.Option("--map", help="Also write the run's map (.ply or .pcd) and its top view (.png beside it).", show_default=False, rich_help_panel=OUTPUT_PANEL)] = None,
    map_voxel: Annotated[Optional[float], typer.Option("--map-voxel", metavar="<float>", help=shown("Voxel size of --map in metres.", "0.1"), show_default=False, rich_help_panel=OUTPUT_PANEL)] = None,
    plot: Annotated[Optional[Path], typer.Option("--plot", metavar="DIR", help="Write the pictures of the trajectory (as lio plot) into DIR.", show_default=False, rich_help_panel=OUTPUT_PANEL)] = None,
    viz: Annotated[bool, typer.Option("--viz", metavar=FLAG, help="Show the run live in rerun's viewer: scans, trajectory, map (needs the viz extra).", rich_help_panel=OUTPUT_PANEL)] = False,
    viz_save: Annotated[Optional[Path], typer.Option("--viz-save", help="Record what --viz shows to FILE.rrd (rerun's viewer opens it).", show_default=False, rich_help_panel=OUTPUT_PANEL)] = None,
    as_json: JsonOpt = False,
    force: ForceOpt = False,
    config: ConfigOpt = None,
    quiet: QuietOpt = False,
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
    voxel_m = _map_voxel(map_file, viz or viz_save is not None, map_voxel)
    inputs = [*input_paths(Path(log)), *(p for p in (config, calib) if p is not None)]
    if gt is not None and Path(gt).exists():
        inputs.append(Path(gt))
    _check_extra_outputs(out, map_file, plot, viz_save, force, inputs)
    if viz or viz_save is not None:
        from ..plots.live import rerun_module

        rerun_module()  # not installed: how to install it, before the work
    if out is not None:
        check_outputs(out, TAG, force, inputs)

    reference = load_reference(Path(log), gt) if gt is not None else None
    view = None
    if viz or viz_save is not None:
        from ..plots.live import LiveView

        view = LiveView(viz_save, viz, log_stem(log))
    with job_progress("odometry", quiet) as update:
        try:
            result = run_odom(OdomJob(Path(log), cfg, voxel_m), progress=update,
                              scans=None if view is None else view.scan)
            if view is not None:
                view.finish(result.alignment, result.map_points)
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
        finally:
            recording = None if view is None else view.close()
    if reference is not None:
        score_odom(result, reference)
    for n in result.notes:
        warn(n)
    for role, choice in result.roles.items():
        note(f"{role}: {choice['topic'] or '-'} ({choice['why']})", quiet)
    written = write_odom_map(result, map_file, force) if map_file is not None else []
    if plot is not None:
        pictures, notes = write_odom_plots(result, reference, plot, force)
        written += pictures
        for n in notes:
            note(n, quiet)
    if to_stdout:
        sys.stdout.write(format_tum(result.trajectory.stamps_ns, result.trajectory.poses))
        sys.stdout.flush()
    else:
        written = write_odom(result, out, force) + written  # last: its metrics name the map and pictures
    if recording is not None:
        written.append(recording)
    _report(result, written, quiet)
    if as_json:
        print_json(result.metrics)


def _map_voxel(map_file: Path | None, viz: bool, map_voxel: float | None) -> float | None:
    """The voxel size of the map of --map FILE or --viz (None: no map)."""
    if map_file is None and not viz:
        if map_voxel is not None:
            raise ConfigError("--map-voxel needs --map FILE (or --viz)")
        return None
    if map_file is not None:
        check_map_suffix(map_file)
    voxel_m = 0.1 if map_voxel is None else map_voxel
    if not (voxel_m > 0 and math.isfinite(voxel_m)):
        raise ConfigError(f"--map-voxel must be a positive number of metres, got {map_voxel}")
    return voxel_m


def _check_extra_outputs(out: Path | None, map_file: Path | None, plot: Path | None, viz_save: Path | None,
                         force: bool, inputs: list[Path]) -> None:
    """--map, --plot and --viz-save: writable, no input, and no file of the run's twice (before any work)."""
    refuse_stdout("--map", map_file, "a point cloud file")
    refuse_stdout("--plot", plot, "PNG files into a folder")
    refuse_stdout("--viz-save", viz_save, "a rerun recording (.rrd)")
    if viz_save is not None and viz_save.suffix.lower() != ".rrd":
        raise ConfigError(f"{viz_save}: a rerun recording is written as .rrd; name the file so")
    named = [] if out is None else [(f"a file of the run (-o {out})", p) for p in run_outputs(out, TAG)]
    if map_file is not None:
        named += [("the map (--map)", map_file), ("the map's top view", map_outputs(map_file)[1])]
    if viz_save is not None:
        named.append(("the recording (--viz-save)", viz_save))
    if plot is not None:
        from ..jobs.plot import plot_files

        named += plot_outputs(plot, plot_files())
    refuse_shared_outputs(named)
    for path in [*(map_outputs(map_file) if map_file is not None else []), *([viz_save] if viz_save else [])]:
        check_writable(path, force, inputs)
    if plot is not None:
        check_plot_dir(plot, plot_files(), force, inputs)


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
    if "path" in m.get("map", {}):
        note(f"map: {plural(m['map']['points'], 'point')} in {m['map']['path']}", quiet)
    if written:
        note(f"wrote {', '.join(str(p) for p in written)}", quiet)


_ALIGNED = {"se3": "SE(3)-aligned rmse over {n} poses",
            "origin": "rmse over {n} poses aligned at the first: the reference's positions lie on a line or a point"}


def register(app: typer.Typer) -> None:
    app.command("odom", help=HELP, no_args_is_help=True, cls=LioCommand)(odom)
