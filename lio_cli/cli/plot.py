"""``lio plot``: trajectories drawn without ground truth (flags -> PlotJob -> run_plot -> write_plot -> print)."""

from __future__ import annotations

import math
from pathlib import Path
from typing import Annotated, Literal, Optional

import typer

from ..errors import ConfigError
from ..io.files.output_paths import check_plot_dir, refuse_stdout
from ..io.sensors.sources import split_source
from ..jobs.plot import PlotJob, plot_files, run_plot, write_plot
from .common import (INPUT_PANEL, OUTPUT_PANEL, ForceOpt, LioCommand, QuietOpt, note, one_of)

HELP = """Draw trajectories: top view, x/y/z and roll/pitch/yaw over time, speed.

Any number of trajectories, overlaid with a legend; no ground truth needed (for errors against one, lio
evaluate). Writes trajectories_xy.png (x-y, equal axes), xyz.png, rpy.png (degrees, R = Rz(yaw) Ry(pitch)
Rx(roll)) and speed.png (between consecutive poses) into the -o folder (default: the current one), one line per
file written.

Each TRAJ is a TUM file, a KITTI file (with --times or --rate), a log topic (run.bag:/ground_truth, an
Odometry, PoseStamped or TransformStamped topic, or a NavSatFix topic: positions only), or a /tf chain
(run.bag:tf:map.base_link), as lio evaluate reads them.

--align MODE moves every trajectory after the first into the first's frame, fitted on their poses paired
by stamp: se3 (rotation and translation), sim3 (and scale), posyaw (translation and yaw), origin (first
poses coincide).

[bold]Examples[/bold]

  lio plot walk.odom.tum walk.gt.tum -o plots/
  lio plot walk.bag:/ground_truth walk.odom.tum --align se3
  lio plot poses.txt --rate 10 -o kitti_plots/
"""

Align = Literal["none", "se3", "sim3", "posyaw", "origin"]
ALIGN_PANEL = "Pairing and alignment"


def plot(
    trajectories: Annotated[list[str], typer.Argument(metavar="TRAJ", help="Trajectories: TUM/KITTI files, LOG:/topic, LOG:tf:parent.child.", show_default=False)],
    times: Annotated[Optional[Path], typer.Option("--times", help="KITTI times file (one stamp in s per line) for KITTI pose files.", show_default=False, rich_help_panel=INPUT_PANEL)] = None,
    rate: Annotated[Optional[float], typer.Option("--rate", metavar="<float>", help="Stamp KITTI pose files at this rate (Hz) instead of --times.", show_default=False, rich_help_panel=INPUT_PANEL)] = None,
    align_mode: Annotated[Align, typer.Option("--align", metavar=one_of(Align), help="Align each trajectory to the first.", rich_help_panel=ALIGN_PANEL)] = "none",
    t_max_diff: Annotated[float, typer.Option("--t-max-diff", metavar="<float>", help="Largest stamp difference (s) of a pose pair for --align.", rich_help_panel=ALIGN_PANEL)] = 0.01,
    output: Annotated[Path, typer.Option("-o", "--output", help="Folder for the PNGs (made if missing).", rich_help_panel=OUTPUT_PANEL)] = Path("."),
    force: ForceOpt = False,
    quiet: QuietOpt = False,
) -> None:
    if not (0 <= t_max_diff and math.isfinite(t_max_diff)):
        raise ConfigError(f"--t-max-diff must be a finite number of seconds >= 0, got {t_max_diff}")
    if times is not None and rate is not None:
        raise ConfigError("give --times or --rate, not both")
    refuse_stdout("-o", output, "PNG files into a folder")
    inputs = [Path(split_source(spec)[0]) for spec in trajectories] + ([times] if times is not None else [])
    check_plot_dir(output, plot_files(), force, inputs)
    result = run_plot(PlotJob(tuple(trajectories), align_mode, t_max_diff, times, rate))
    for line in result.notes:
        note(line, quiet)
    for path in write_plot(result, output, force):
        note(f"wrote {path}", quiet)


def register(app: typer.Typer) -> None:
    app.command("plot", help=HELP, short_help="Draw trajectories: top view, x/y/z, roll/pitch/yaw, speed.",
                no_args_is_help=True, cls=LioCommand)(plot)
