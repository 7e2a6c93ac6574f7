"""Benchmarks time lio as an installed machine runs it: with Python's bytecode cache.

Some sandboxes and CI images set PYTHONDONTWRITEBYTECODE; every lio process a benchmark starts would then
compile lio's own modules from source (about 0.1 s that no installed lio pays, since pip-installed or once-run
code has its cache). ``use_bytecode_cache`` lets this process and its children write the cache and warms it
by importing every command module once."""

from __future__ import annotations

import os
import subprocess
import sys


def use_bytecode_cache() -> None:
    os.environ.pop("PYTHONDONTWRITEBYTECODE", None)  # inherited by every subprocess started after this
    sys.dont_write_bytecode = False
    subprocess.run([sys.executable, "-c", "from lio_cli.cli.app import register_commands; register_commands()"],
                   check=True, stdout=subprocess.DEVNULL)
