"""lio config COMMAND: the default configuration, commented, on stdout or in a file that --config reads back."""

from __future__ import annotations

import pytest

from lio_cli.cli.app import main
from lio_cli.cli.config import MODELS, template
from lio_cli.config import load_config


@pytest.mark.parametrize("command", sorted(MODELS))
def test_the_printed_configuration_is_the_defaults_with_comments(command, capsys, tmp_path):
    assert main(["config", command]) == 0
    out, err = capsys.readouterr()
    assert out == template(command) and err == ""
    assert out.startswith(f"# lio {command}: default configuration (lio config {command}).\n")
    assert sum(line.lstrip().startswith("# ") for line in out.splitlines()) > 40
    path = tmp_path / f"{command}.yaml"
    path.write_text(out)
    # as the commands read --config
    assert load_config(MODELS[command], path) == MODELS[command]()


def test_output_file_is_written_once_without_force(capsys, tmp_path):
    path = tmp_path / "odom.yaml"
    assert main(["config", "odom", "-o", str(path)]) == 0
    assert capsys.readouterr().err == f"wrote {path}\n"
    assert path.read_text() == template("odom")
    path.write_text("mine\n")
    assert main(["config", "odom", "-o", str(path)]) == 2
    assert capsys.readouterr().err == f"lio: error: {path}: already exists; pass --force to overwrite it\n"
    assert path.read_text() == "mine\n"
    assert main(["config", "odom", "-o", str(path), "--force", "-q"]) == 0
    assert capsys.readouterr().err == "" and path.read_text() == template("odom")


def test_unknown_command_is_one_line_and_exit_2(capsys):
    assert main(["config", "slam"]) == 2
    assert capsys.readouterr().err == ("lio: error: Invalid value for 'COMMAND': 'slam' is not one of 'odom', "
                                       "'deskew', 'fuse', 'calibrate'; see 'lio config --help'\n")
