"""The ``lio`` entry point: the typer app, global options, and the one place errors become exit codes."""

from __future__ import annotations

import gc
import importlib
import signal
import sys
from typing import Annotated, Optional

import typer

try:  # typer vendors click since 0.2x; older releases depend on it
    from typer._click.exceptions import ClickException as _ClickException
except ImportError:  # pragma: no cover - depends on the installed typer
    from click.exceptions import ClickException as _ClickException

from .. import __version__
from ..errors import LioError
from ..io.files.atomic import is_no_space, keep_count, take_back
from ..gc_pause import freeze_start_up
from .common import FLAG, RUN_PANEL, LioGroup, err_console

app = typer.Typer(
    name="lio",
    help=(
        "LiDAR-inertial odometry over recorded robot logs (ROS 1 bags, ROS 2 bags, MCAP), no ROS needed.\n\n"
        "Data goes to stdout or files, logs and progress to stderr. Exit codes: 0 ok, 1 processing failed, "
        "2 bad input or usage."
    ),
    no_args_is_help=True,
    pretty_exceptions_enable=False,
    rich_markup_mode="rich",
    context_settings={"help_option_names": ["-h", "--help"]},
    cls=LioGroup,
)

_state = {"debug": False, "own_process": False}

# One module per command; each exposes register(app).
COMMANDS = ["info", "odom", "calibrate", "deskew", "fuse", "evaluate", "plot", "simulate", "batch", "config"]


def _version(value: bool) -> None:
    if value:
        typer.echo(f"lio {__version__}")
        raise typer.Exit()


@app.callback()
def _main(
    version: Annotated[Optional[bool], typer.Option("--version", callback=_version, is_eager=True, metavar=FLAG, rich_help_panel=RUN_PANEL, help="Print the version and exit.")] = None,
    debug: Annotated[bool, typer.Option("--debug", metavar=FLAG, rich_help_panel=RUN_PANEL, help="Show tracebacks on errors.")] = False,
) -> None:
    _state["debug"] = debug


_registered: set[str] = set()


def register_commands(names: list[str] | None = None) -> typer.Typer:
    """Import and register command modules (all by default); each module registers once."""
    for name in names or COMMANDS:
        if name not in _registered:
            importlib.import_module(f"{__package__}.{name}").register(app)
            _registered.add(name)
    for cmd in app.registered_commands:
        if cmd.help:
            cmd.help = reflow(cmd.help)
    return app


def reflow(text: str) -> str:
    """A command's help for any terminal width: rich keeps every line break of the text, so the lines of each prose
    paragraph are joined for rich to wrap; a paragraph with an indented line (examples, a table of inputs) stays
    as written."""
    paragraphs = text.split("\n\n")
    return "\n\n".join(p if any(line[:1].isspace() for line in p.splitlines()) else
                        " ".join(line.strip() for line in p.splitlines()) for p in paragraphs)


def usage_line(err: _ClickException) -> str:
    """A usage error as one line: the reason, and where the help is."""
    msg = " ".join(err.format_message().replace("Value error, ", "").split()).rstrip(".")
    ctx = getattr(err, "ctx", None)
    where = f"; see '{ctx.command_path} --help'" if ctx is not None else ""
    return f"lio: error: {msg}{where}"


def _command_in(args: list[str]) -> str | None:
    return next((a for a in args if not a.startswith("-")), None)


class Terminated(BaseException):
    """SIGTERM arrived: unwind like Ctrl-C (temporary files removed on the way), exit 143."""


def _on_sigterm(signum, frame) -> None:  # noqa: ARG001 - signal handler signature
    raise Terminated()


def _interrupted(what: str, code: int) -> int:
    take_back()  # the outputs this run had already put in place: an interrupted run leaves none
    sys.stderr.write(f"lio: {what}; nothing half-written was left behind\n")  # no import on the way out
    sys.stderr.flush()
    return code


def main(argv: list[str] | None = None) -> int:
    """Run the CLI; map LioError to one stderr line and its exit code (Ctrl-C 130, SIGTERM 143)."""
    args = list(argv if argv is not None else sys.argv[1:])
    previous_term = signal.getsignal(signal.SIGTERM)
    ours = previous_term is signal.SIG_DFL or getattr(previous_term, "lio_start_up", False)
    if ours:
        signal.signal(signal.SIGTERM, _on_sigterm)
    try:
        return _main_guarded(args)
    except KeyboardInterrupt:  # while an error line was being printed
        return _interrupted("interrupted", 130)
    except Terminated:
        return _interrupted("terminated", 143)
    finally:
        if ours:
            signal.signal(signal.SIGTERM, signal.SIG_DFL)


def _main_guarded(args: list[str]) -> int:
    _state["debug"] = "--debug" in args
    try:
        # import only the command asked for: its dependencies (kiss-icp, scipy, matplotlib) are slow to load
        wanted = _command_in(args)
        if wanted != "batch":  # a stopped batch keeps its finished runs
            keep_count()
        if wanted in COMMANDS:
            register_commands([wanted])
        elif not (args and all(a in ("--version", "--debug") for a in args) and "--version" in args):
            register_commands()
        if _state["own_process"]:
            freeze_start_up()
        rc = app(args=args, prog_name="lio", standalone_mode=False)
    except typer.Exit as ex:
        return ex.exit_code
    except LioError as err:
        if _state["debug"]:
            raise
        err_console.print(f"lio: error: {err}", markup=False)
        return err.exit_code
    except KeyboardInterrupt:
        return _interrupted("interrupted", 130)
    except Terminated:
        return _interrupted("terminated", 143)
    except typer.Abort:
        return 1
    except _ClickException as err:  # usage errors (unknown option, bad choice...): one line, exit 2
        err_console.print(usage_line(err), markup=False)
        return err.exit_code
    except Exception as err:  # anything else is a bug
        if _state["debug"]:
            raise
        if is_no_space(err):  # a full device where no writer said which output: the path the system names
            where = getattr(err, "filename", None) or "the output's device"
            err_console.print(f"lio: error: no space left on device: {where}", markup=False)
            return 1
        take_back()  # a bug's run leaves nothing half-done behind either
        err_console.print(f"lio: internal error: {type(err).__name__}: {err} (run with --debug for the traceback)", markup=False)
        return 1
    if rc == 130:  # typer turns Ctrl-C inside a command into a return value of 130
        return _interrupted("interrupted", 130)
    return rc if isinstance(rc, int) else 0


def entry() -> None:  # pragma: no cover - console script
    """The ``lio`` process: one command, then exit. The cyclic collector is off while the command's modules
    load and their objects are frozen out of its passes (``freeze_start_up``), then frozen again before exit
    so the interpreter's last full pass walks nothing."""
    gc.disable()
    _state["own_process"] = True
    rc = main()
    gc.freeze()
    sys.exit(rc)
