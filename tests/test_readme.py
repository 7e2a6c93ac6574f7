"""The README's walkthrough runs as written: its setup line, then every ``$ lio ...`` line of its console blocks
in order, in one scratch folder with the sample logs linked in (``python -m lio_cli`` standing in for ``lio``),
each exiting 0. A command that stopped on an earlier step's file (``walk.metrics.json: already exists``) fails it."""

import os
import re
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
README = ROOT / "README.md"
SCRATCH = "/tmp/walk"  # the folder the README works in; the test's own tmp_path stands in for it


def walkthrough(text: str) -> tuple[str, list[str]]:
    """(the setup line, the ``lio`` commands of the console blocks in order) of the README's walkthrough."""
    section = text.split("## A five-minute walkthrough", 1)[1].split("\n## ", 1)[0]
    setup = next(line for block in re.findall(r"```bash\n(.*?)```", section, re.S) for line in block.splitlines()
                 if SCRATCH in line)
    commands = [line[2:] for block in re.findall(r"```console\n(.*?)```", section, re.S)
                for line in block.splitlines() if line.startswith("$ ")]
    return setup, commands


def test_the_walkthrough_is_found():
    setup, commands = walkthrough(README.read_text())
    assert setup.startswith("mkdir -p /tmp/walk && ln -sfn")
    assert len(commands) >= 10 and all(c.startswith("lio ") for c in commands)
    assert commands[0].startswith("lio simulate ") and commands[-1].startswith("lio batch ")


def run_lio_lines(commands: list[str], cwd: Path) -> None:
    """Run each ``lio ...`` line with bash (its quoting and globs as a user's shell has them) in ``cwd``."""
    env = {**os.environ, "PYTHONPATH": str(ROOT), "COLUMNS": "80"}
    lio = f"{sys.executable} -m lio_cli"
    for command in commands:
        done = subprocess.run(["bash", "-c", lio + command[len("lio"):]], cwd=cwd, env=env, capture_output=True,
                              text=True)
        assert done.returncode == 0, f"$ {command}\n{done.stderr}"


def test_the_walkthrough_runs_in_sequence(tmp_path):
    setup, commands = walkthrough(README.read_text())
    here = tmp_path / "walk"
    done = subprocess.run(["bash", "-c", setup.split("#")[0].replace(SCRATCH, str(here))], cwd=ROOT,
                          capture_output=True, text=True)
    assert done.returncode == 0, done.stderr
    assert (here / "sample_logs").resolve() == ROOT / "sample_logs"
    run_lio_lines(commands, here)
    assert sorted(p.name for p in (here / "results").iterdir()) == [
        "handheld", "planar", "summary.csv", "summary.json", "walk"]
