"""Every command's --help reads well in an 80-column terminal: prose paragraphs wrap evenly, examples keep
their lines."""

from __future__ import annotations

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
