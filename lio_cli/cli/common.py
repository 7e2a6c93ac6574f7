"""Shared CLI plumbing: consoles, option types, JSON output, progress bars, error mapping."""

from __future__ import annotations

import sys
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import Annotated, Any, Literal, Optional, get_args

import typer
from typer.core import TyperCommand, TyperGroup


class _Console:
    """A rich ``Console`` made on first use: a quiet run that prints nothing never pays for importing rich.console.
    Attributes and methods are the console's."""

    def __init__(self, **options: Any) -> None:
        self._options = options
        self._console = None

    @property
    def console(self):
        if self._console is None:
            from rich.console import Console

            self._console = Console(**self._options)
        return self._console

    def __getattr__(self, name: str) -> Any:
        return getattr(self.console, name)


err_console = _Console(stderr=True, highlight=False, soft_wrap=True, emoji=False)  # ":100:" stays as typed
out_console = _Console(highlight=False, soft_wrap=True, emoji=False)

# The option panels of every command's --help, in this order; options of one concern share a panel.
INPUT_PANEL = "Input and topics"
MOTION_PANEL = "Motion model"
CALIBRATION_PANEL = "Calibration"
OUTPUT_PANEL = "Output"
RUN_PANEL = "Run"
FLAG = ""  # metavar of an on/off flag: no <bool> placeholder beside it


def one_of(choices: Any) -> str:
    """The metavar of a choice (a Literal type): its values, wrapping between values in a narrow column."""
    return "<" + " | ".join(get_args(choices)) + ">"


def shown(help: str, default: Any) -> str:
    """``help`` with ``[default: ...]`` as typer shows a default, for options whose default lives in the
    configuration (the flag itself defaults to None: not given, so --config's value stands)."""
    text = ("on" if default else "off") if isinstance(default, bool) else default
    return f"{help} [dim]\\[default: {text}][/dim]"


def config_default(model: type, dotted: str) -> Any:
    """The default of a configuration field, by its dotted name (``fusion.alpha``)."""
    node = model()
    for key in dotted.split("."):
        node = getattr(node, key)
    return node


class _HelpInRunPanel:
    """--help/-h shown in the Run panel without a <bool> placeholder."""

    def get_help_option(self, ctx):
        opt = super().get_help_option(ctx)
        if opt is not None:
            opt.metavar, opt.rich_help_panel = FLAG, RUN_PANEL
        return opt


class LioCommand(_HelpInRunPanel, TyperCommand):
    """Every lio command's click class."""


class LioGroup(_HelpInRunPanel, TyperGroup):
    """The ``lio`` group's click class: typer's --install-completion and --show-completion in the Run panel."""

    def get_params(self, ctx):
        params = super().get_params(ctx)
        for p in params:
            if p.name in ("install_completion", "show_completion"):
                p.metavar, p.rich_help_panel = FLAG, RUN_PANEL
        return params


# Options many commands share, so they read the same everywhere.
LogArg = Annotated[Path, typer.Argument(metavar="LOG", help="ROS 1 .bag (or a folder of split bags), ROS 2 bag folder or metadata.yaml, or .mcap file.", show_default=False)]
InputFormat = Literal["ros1", "ros2", "mcap"]
FormatOpt = Annotated[Optional[InputFormat], typer.Option("--format", metavar=one_of(InputFormat), help="Input format, overriding detection.", show_default=False, rich_help_panel=INPUT_PANEL)]
JsonOpt = Annotated[bool, typer.Option("--json", metavar=FLAG, help="Print a machine-readable summary on stdout.", rich_help_panel=OUTPUT_PANEL)]
QuietOpt = Annotated[bool, typer.Option("--quiet", "-q", metavar=FLAG, help="No progress bar or notes on stderr (errors still print).", rich_help_panel=RUN_PANEL)]
ForceOpt = Annotated[bool, typer.Option("--force", metavar=FLAG, help="Overwrite existing outputs.", rich_help_panel=OUTPUT_PANEL)]
LidarTopicOpt = Annotated[Optional[str], typer.Option("--lidar-topic", help=shown("PointCloud2 or LaserScan topic.", "the only one"), show_default=False, rich_help_panel=INPUT_PANEL)]
ImuTopicOpt = Annotated[Optional[str], typer.Option("--imu-topic", help=shown("sensor_msgs/Imu topic.", "the only one"), show_default=False, rich_help_panel=INPUT_PANEL)]
WheelTopicOpt = Annotated[Optional[str], typer.Option("--wheel-topic", help=shown("Wheel odometry topic: nav_msgs/Odometry or TwistStamped.", "the only one"), show_default=False, rich_help_panel=INPUT_PANEL)]
PointTimeOpt = Annotated[Optional[str], typer.Option("--point-time", help=shown("Per-point time, overriding detection: velodyne, ouster, livox, hesai, azimuth, none, FIELD:UNIT[:abs|rel] with UNIT s, ms, us or ns, or SEC+NSEC[:abs|rel] (e.g. t:ns, time_sec+time_nsec).", "detected"), show_default=False, rich_help_panel=INPUT_PANEL)]
BaseFrameOpt = Annotated[Optional[str], typer.Option("--base-frame", help=shown("Base frame in /tf_static.", "base_link, base or base_footprint"), show_default=False, rich_help_panel=INPUT_PANEL)]
ConfigOpt = Annotated[Optional[Path], typer.Option("--config", help="YAML configuration: a run's .config.yaml or lio config's output; flags override its fields.", show_default=False, rich_help_panel=RUN_PANEL)]
CalibOpt = Annotated[Optional[Path], typer.Option("--calib", help="Calibration YAML (lio calibrate): T_base_imu, T_base_lidar, imu_time_offset_s, used where /tf_static is silent.", show_default=False, rich_help_panel=CALIBRATION_PANEL)]
ImuTimeOffsetOpt = Annotated[Optional[float], typer.Option("--imu-time-offset", help="Seconds added to IMU stamps to put them on the LiDAR's clock (overrides --calib's imu_time_offset_s).", show_default=False, rich_help_panel=CALIBRATION_PANEL)]
PreferCalibOpt = Annotated[bool, typer.Option("--prefer-calib", metavar=FLAG, help="Use --calib's extrinsics even where the log's /tf_static gives them (config: calibration.prefer_file: true); a note says how far apart the two are either way.", rich_help_panel=CALIBRATION_PANEL)]


def prefer_calib_override(prefer: bool, calib: Path | None, config: Path | None) -> bool | None:
    """--prefer-calib as a configuration override (None: as the configuration says); it needs a calibration."""
    if prefer and calib is None and config is None:
        from ..errors import ConfigError

        raise ConfigError("--prefer-calib prefers the extrinsics of --calib: give --calib FILE")
    return True if prefer else None


def print_json(obj: Any) -> None:
    """JSON on stdout (numpy scalars and arrays converted)."""
    from ..jobs.outputs import json_text

    sys.stdout.write(json_text(obj))
    sys.stdout.flush()


def note(msg: str, quiet: bool = False) -> None:
    """A line for people on stderr."""
    if not quiet:
        err_console.print(msg)


def next_step(args: list[str], quiet: bool = False) -> None:
    """``next: lio ARGS...``: a command to run next, quoted for a POSIX shell so it pastes as printed."""
    import shlex

    note("next: " + shlex.join(["lio", *(str(a) for a in args)]), quiet)


def plural(n: int, word: str, many: str | None = None) -> str:
    """``1 run``, ``2 runs`` (``many``: the plural when it is not word + s)."""
    return f"{n} {word if n == 1 else many or word + 's'}"


def warn(msg: str) -> None:
    """A warning on stderr; shown even with --quiet."""
    err_console.print(f"[yellow]lio: warning:[/yellow] {msg}")


@contextmanager
def _bar(description: str, total: float | None, quiet: bool):
    """(rich Progress, task id) on stderr when it is a terminal and not --quiet, else (None, None)."""
    if quiet or not sys.stderr.isatty():
        yield None, None
        return
    from rich.progress import BarColumn, Progress, TextColumn, TimeElapsedColumn, TimeRemainingColumn

    with Progress(TextColumn("{task.description}"), BarColumn(), TextColumn("{task.percentage:>3.0f}%"),
                  TimeElapsedColumn(), TimeRemainingColumn(), console=err_console.console, transient=True) as prog:
        yield prog, prog.add_task(description, total=total)


@contextmanager
def progress_bar(description: str, total: float | None, quiet: bool) -> Iterator[Callable[[float], None]]:
    """Yield ``advance(n)``; a rich bar on stderr only when it is a terminal and not --quiet."""
    with _bar(description, total, quiet) as (prog, task):
        yield (lambda n=1.0: None) if prog is None else (lambda n=1.0: prog.advance(task, n))


@contextmanager
def job_progress(description: str, quiet: bool) -> Iterator[Callable[[int, int | None], None]]:
    """Yield ``update(done, total)``, the progress callback jobs take (a bar as ``progress_bar``)."""
    with _bar(description, None, quiet) as (prog, task):
        yield (lambda done, total=None: None) if prog is None else \
            (lambda done, total=None: prog.update(task, completed=done, total=total))
