"""Every command's --help reads well in an 80-column terminal: prose paragraphs wrap evenly, examples keep
their lines."""

from __future__ import annotations

import re

import pytest

from lio_cli.cli.app import COMMANDS, main, reflow


def test_reflow_joins_prose_and_keeps_indented_paragraphs():
    text = "Summary line.\n\nOne paragraph wrapped\nat some width, on\nthree lines.\n\n[bold]Examples[/bold]\n\n  lio a\n  lio b"
    assert reflow(text) == ("Summary line.\n\nOne paragraph wrapped at some width, on three lines.\n\n"
                            "[bold]Examples[/bold]\n\n  lio a\n  lio b")


def _description(capsys, command: str) -> list[str]:
    assert main([command, "--help"]) == 0
    out = capsys.readouterr().out
    return out[: out.index("╭─")].splitlines()  # the text above the arguments' and options' panels


@pytest.mark.parametrize("command", COMMANDS)
def test_help_prose_is_not_ragged_at_80_columns(command, capsys, monkeypatch):
    """Before: help texts wrapped at 110 columns came out as a full line, then a few words, in turn."""
    monkeypatch.setenv("COLUMNS", "80")
    lines = _description(capsys, command)
    assert max(len(line) for line in lines) <= 80
    prose = [i for i, line in enumerate(lines) if line[:1] == " " and line[1:2].strip()]  # rich's one-space margin
    short = [lines[i] for i in prose if i + 1 in prose and len(lines[i].rstrip()) < 50]
    assert not short, "\n".join(short)


# ---- 80 columns: no cut option name, no line past 80, panels, defaults, choices, examples ----------------------

PANELS = {"Arguments", "Input and topics", "Motion model", "Calibration", "Output", "Run",
          # panels of one command's own concerns
          "Commands", "Sensors", "Pairing and alignment", "Metrics"}


def _click_command(name: str | None):
    from typer.main import get_command

    from lio_cli.cli.app import app, register_commands

    register_commands()
    group = get_command(app)
    return group if name is None else group.commands[name]


def _help_80(command: str | None, capsys, monkeypatch) -> str:
    monkeypatch.setenv("COLUMNS", "80")
    monkeypatch.setenv("LINES", "25")
    monkeypatch.delenv("TERMINAL_WIDTH", raising=False)
    assert main([*([command] if command else []), "--help"]) == 0
    out, err = capsys.readouterr()
    assert err == ""
    return out


@pytest.mark.parametrize("command", [None, *COMMANDS])
def test_help_fits_80_columns_with_every_option_in_full(command, capsys, monkeypatch):
    """Before: simulate's 40 options in one panel cut --time-conventi… and --imu-time-offs…, odom's examples
    wrapped mid-command and flags showed a <bool> placeholder."""
    out = _help_80(command, capsys, monkeypatch)
    lines = out.splitlines()
    assert max(len(line) for line in lines) <= 80
    assert "…" not in out and "<bool>" not in out
    params = [p for p in _click_command(command).params if not getattr(p, "hidden", False)]
    for p in params:
        if p.param_type_name != "option":
            continue
        for opt in [*p.opts, *p.secondary_opts]:
            assert re.search(rf"(?<![\w-]){re.escape(opt)}(?![\w-])", out), f"{opt} is not shown in full"
    titles = set(re.findall(r"╭─ (.+?) ─", out))
    assert titles <= PANELS, titles - PANELS
    assert "Options" not in titles  # every option sits in a named panel


def _examples(help_text: str) -> list[str]:
    block = help_text.split("[bold]Examples[/bold]", 1)[1] if "[bold]Examples[/bold]" in help_text else ""
    return [line.strip() for line in block.splitlines() if line.strip().startswith("lio ")]


@pytest.mark.parametrize("command", COMMANDS)
def test_examples_are_one_short_command_per_line(command, capsys, monkeypatch):
    """Each example is one line of the help as printed at 80 columns, so it can be pasted."""
    out = _help_80(command, capsys, monkeypatch)
    examples = _examples(_click_command(command).help)
    assert len(examples) >= 2
    printed = {line.strip() for line in out.splitlines()}
    for example in examples:
        assert example in printed, example
        assert " && " not in example and "\\" not in example


@pytest.mark.parametrize("command, option, choices, default", [
    ("odom", "--deskew", ["auto", "imu", "constant-velocity", "none"], "auto"),
    ("odom", "--prior", ["imu", "constant-velocity", "wheel", "none"], "imu"),
    ("odom", "--fusion", ["ekf", "complementary"], "ekf"),
    ("deskew", "--motion", ["auto", "trajectory", "imu", "constant-velocity"], "auto"),
    ("fuse", "--estimator", ["auto", "ekf", "planar", "complementary"], "auto"),
    ("evaluate", "--align", ["none", "se3", "sim3", "scale", "origin", "posyaw"], "se3"),
    ("simulate", "--time-convention", ["velodyne", "ouster", "livox", "hesai"], "velodyne"),
])
def test_choices_and_defaults_are_shown(command, option, choices, default, capsys, monkeypatch):
    """Each choice and the default in the option's row (at 200 columns, where nothing wraps)."""
    monkeypatch.setenv("COLUMNS", "200")
    assert main([command, "--help"]) == 0
    row = next(line for line in capsys.readouterr().out.splitlines() if line.startswith(f"│ {option} "))
    assert "<" + " | ".join(choices) + ">" in row and f"[default: {default}]" in row, row


@pytest.mark.parametrize("argv, line", [
    (["odom", "missing.bag", "--prior", "gps"],
     "Invalid value for '--prior': 'gps' is not one of 'imu', 'constant-velocity', 'wheel', 'none'; "
     "see 'lio odom --help'"),
    (["odom", "missing.bag", "--deskew", "always"],
     "Invalid value for '--deskew': 'always' is not one of 'auto', 'imu', 'constant-velocity', 'none'; "
     "see 'lio odom --help'"),
    (["fuse", "missing.bag", "--estimator", "ukf"],
     "Invalid value for '--estimator': 'ukf' is not one of 'auto', 'ekf', 'planar', 'complementary'; see 'lio fuse --help'"),
    (["evaluate", "a.tum", "b.tum", "--gt-stamp-unit", "min"],
     "Invalid value for '--gt-stamp-unit': 'min' is not one of 's', 'ms', 'us', 'ns'; see 'lio evaluate --help'"),
    (["odom", "missing.bag", "--alpha", "2"],
     "Invalid value for '--alpha': Input should be less than or equal to 1; see 'lio odom --help'"),
    (["info", "--no-such-option", "x"], "No such option: --no-such-option; see 'lio info --help'"),
])
def test_a_bad_choice_is_one_line_at_parse_time(argv, line, capsys, tmp_path, monkeypatch):
    """Checked before the log is opened (missing.bag does not exist): one line, exit 2, no pydantic wording."""
    monkeypatch.chdir(tmp_path)
    assert main(argv) == 2
    out, err = capsys.readouterr()
    assert (out, err) == ("", f"lio: error: {line}\n")
    assert not any(tmp_path.iterdir())


def test_flags_show_no_placeholder_and_the_help_option_is_in_the_run_panel(capsys, monkeypatch):
    out = _help_80("odom", capsys, monkeypatch)
    run = out[out.index("╭─ Run "):]
    assert re.search(r"│ --help\s+-h\s+Show this message and exit\.", run)
    assert re.search(r"│ --no-wheel\s+Ignore wheel odometry", out)


@pytest.mark.parametrize("words, cword, expected", [
    ("lio od", 1, "odom"),
    ("lio odom x.bag --prior ", 4, "imu\nconstant-velocity\nwheel\nnone"),
    ("lio config ", 2, "odom\ndeskew\nfuse\ncalibrate"),
])
def test_shell_completion_through_the_entry_point(words, cword, expected, capsys, monkeypatch):
    """What `lio --install-completion` installs asks the program itself: commands, options and choices."""
    monkeypatch.setenv("_LIO_COMPLETE", "complete_bash")
    monkeypatch.setenv("COMP_WORDS", words)
    monkeypatch.setenv("COMP_CWORD", str(cword))
    with pytest.raises(SystemExit) as exit_:
        main([])
    assert exit_.value.code == 0
    assert capsys.readouterr().out.strip() == expected


def test_help_of_the_console_script_at_80_columns():
    """The installed `lio`, not a test's in-process call: same width rules, the program named lio."""
    import os
    import subprocess
    import sys
    from pathlib import Path

    lio = Path(sys.executable).parent / "lio"
    env = {**os.environ, "COLUMNS": "80", "PYTHONPATH": str(Path(__file__).resolve().parents[2])}
    res = subprocess.run([str(lio), "simulate", "--help"], capture_output=True, text=True, timeout=60, env=env)
    assert res.returncode == 0 and res.stderr == ""
    lines = res.stdout.splitlines()
    assert "Usage: lio simulate [OPTIONS]" in res.stdout
    assert max(map(len, lines)) <= 80 and "…" not in res.stdout and "--time-convention" in res.stdout
