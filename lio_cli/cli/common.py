"""Shared CLI plumbing: consoles, option types, JSON output, progress bars, error mapping."""

from __future__ import annotations

import sys
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import Annotated, Any, Optional

import typer


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


err_console = _Console(stderr=True, highlight=False, soft_wrap=True)
out_console = _Console(highlight=False, soft_wrap=True)

# Options many commands share, so they read the same everywhere.
LogArg = Annotated[Path, typer.Argument(help="Log: ROS 1 .bag (or a folder of split bags), ROS 2 bag folder or metadata.yaml, or .mcap file.", show_default=False)]
FormatOpt = Annotated[Optional[str], typer.Option("--format", help="Input format, overriding detection: ros1, ros2 or mcap.", show_default=False)]
JsonOpt = Annotated[bool, typer.Option("--json", help="Print a machine-readable summary on stdout.")]
QuietOpt = Annotated[bool, typer.Option("--quiet", "-q", help="No progress bar or notes on stderr (errors still print).")]
ForceOpt = Annotated[bool, typer.Option("--force", help="Overwrite existing outputs.")]
LidarTopicOpt = Annotated[Optional[str], typer.Option("--lidar-topic", help="PointCloud2 or LaserScan topic (default: the only one).", show_default=False)]
ImuTopicOpt = Annotated[Optional[str], typer.Option("--imu-topic", help="sensor_msgs/Imu topic (default: the only one).", show_default=False)]
WheelTopicOpt = Annotated[Optional[str], typer.Option("--wheel-topic", help="Wheel odometry topic, nav_msgs/Odometry or TwistStamped (default: the only one).", show_default=False)]
PointTimeOpt = Annotated[Optional[str], typer.Option("--point-time", help="Per-point time convention, overriding detection: velodyne, ouster, livox, hesai, azimuth, none, FIELD:UNIT[:abs|rel] (UNIT s|ms|us|ns) or SEC_FIELD+NSEC_FIELD[:abs|rel] (e.g. time_sec+time_nsec).", show_default=False)]
ConfigOpt = Annotated[Optional[Path], typer.Option("--config", help="YAML configuration (see the .config.yaml a run writes).", show_default=False)]
PreferCalibOpt = Annotated[bool, typer.Option("--prefer-calib", help="Use --calib's extrinsics even where the log's /tf_static gives them (config: calibration.prefer_file: true); a note says how far apart the two are either way.", rich_help_panel="Calibration")]
BaseFrameOpt = Annotated[Optional[str], typer.Option("--base-frame", help="Name of the base frame in /tf_static (default: base_link, base or base_footprint).", show_default=False)]


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
