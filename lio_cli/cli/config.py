"""``lio config``: a command's default configuration as commented YAML, to edit and pass back with --config."""

from __future__ import annotations

import sys
from pathlib import Path
from typing import Annotated, Literal, Optional

import typer

from ..config.calibrate import CalibrateConfig
from ..config.deskew import DeskewConfig
from ..config.fuse import FuseConfig
from ..config.odom import OdomConfig
from ..config.template import commented_yaml
from ..io.files.atomic import check_writable, write_text_atomic
from .common import OUTPUT_PANEL, ForceOpt, LioCommand, QuietOpt, note

MODELS = {"odom": OdomConfig, "deskew": DeskewConfig, "fuse": FuseConfig, "calibrate": CalibrateConfig}
Command = Literal["odom", "deskew", "fuse", "calibrate"]

HELP = """Print COMMAND's default configuration as YAML, a comment above every field saying what it is.

Edit it and pass it back: `lio COMMAND LOG --config FILE`. Every field may be left out (its default
stands), and flags given with --config replace its fields one by one. A run's own .config.yaml is the
same model, resolved (topics, base frame and calibration filled in).

[bold]Examples[/bold]

  lio config odom                       # on stdout
  lio config odom -o odom.yaml
  lio odom walk.bag --config odom.yaml
"""


def template(command: str) -> str:
    """The commented default configuration of ``command``."""
    header = (f"lio {command}: default configuration (lio config {command}).\n"
              f"Use with: lio {command} LOG --config FILE. Leave out what you keep; flags override fields.")
    return commented_yaml(MODELS[command](), header)


def config_cmd(
    command: Annotated[Command, typer.Argument(metavar="COMMAND", show_choices=False, help="Whose configuration: odom, deskew, fuse or calibrate.", show_default=False)],
    output: Annotated[Optional[Path], typer.Option("-o", "--output", help="Write it to this file instead of stdout.", show_default=False, rich_help_panel=OUTPUT_PANEL)] = None,
    force: ForceOpt = False,
    quiet: QuietOpt = False,
) -> None:
    text = template(command)
    if output is None:
        sys.stdout.write(text)
        sys.stdout.flush()
        return
    check_writable(output, force)
    write_text_atomic(output, text, force)
    note(f"wrote {output}", quiet)


def register(app: typer.Typer) -> None:
    app.command("config", help=HELP, short_help="A command's default configuration, commented, as YAML.",
                no_args_is_help=True, cls=LioCommand)(config_cmd)
