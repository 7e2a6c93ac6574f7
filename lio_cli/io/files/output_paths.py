"""Outputs of one run: the names of the files written beside its main output (one rule for every command), and
the outputs checked against each other before any work: no two of them may be the same file, or the later write
would replace the earlier (``-o f.tum --cov f.tum``), whatever ``--force`` says."""

from __future__ import annotations

import os
from collections.abc import Iterable
from pathlib import Path

from ...errors import ConfigError, InputError
from .atomic import check_writable


def _identity(path: Path) -> tuple:
    """The same key for two spellings of one file: its inode when it exists, else its resolved path."""
    try:
        st = os.stat(path)
        return ("inode", st.st_dev, st.st_ino)
    except OSError:
        return ("path", os.path.normcase(os.path.realpath(path)))


def tagged_name(out: Path, tag: str) -> str:
    """``out``'s name without its suffix, ending in ``.TAG`` once: the stem of the files a command ``tag`` writes
    beside ``out`` (walk.tum and walk.odom.tum -> walk.odom; odom.tum -> odom; a folder walk_ros2 ->
    walk_ros2.deskew), so no two commands' side files share a name."""
    out = Path(out)
    name = out.name[: -len(out.suffix)] if out.suffix else out.name
    return name if name == tag or name.endswith(f".{tag}") else f"{name}.{tag}"


def side_file(out: Path, tag: str, suffix: str) -> Path:
    """The file ``suffix`` (e.g. ``.metrics.json``) that command ``tag`` writes beside ``out``: walk.odom.tum ->
    walk.odom.metrics.json; walk_deskewed.bag -> walk_deskewed.deskew.metrics.json."""
    return Path(out).with_name(tagged_name(out, tag) + suffix)


def refuse_shared_outputs(outputs: Iterable[tuple[str, Path]]) -> None:
    """``outputs``: (what it is, e.g. "the trajectory (-o)", path). One line naming both when two coincide."""
    seen: dict[tuple, str] = {}
    for what, path in outputs:
        key = _identity(Path(path))
        if key in seen:
            raise ConfigError(f"{path}: would be both {seen[key]} and {what}; give each output its own path")
        seen[key] = what


def plot_outputs(plot: Path | None, names: Iterable[str], kind: str = "file") -> list[tuple[str, Path]]:
    """The (what, path) entries of a ``--plot`` folder and the files it will hold, for ``refuse_shared_outputs``."""
    if plot is None:
        return []
    return [("the plot folder (--plot)", plot), *((f"the {kind} {name} of --plot {plot}", plot / name) for name in names)]


def check_plot_dir(folder: Path, names: Iterable[str], force: bool, inputs: list[Path]) -> None:
    """A ``--plot`` folder: a folder (or nothing yet: created when the plots are made) whose files ``names`` may
    be written."""
    if folder.exists() and not folder.is_dir():
        raise InputError(f"{folder}: exists and is not a folder")
    if not folder.exists():
        check_writable(folder, force, inputs)
        return
    for name in names:
        check_writable(folder / name, force, inputs)


def refuse_stdout(option: str, path: Path | str | None, what: str) -> None:
    """``-`` for an option that writes a file or folder (not standard output)."""
    if path is not None and str(path) == "-":
        raise ConfigError(f"{option} writes {what}, not standard output: give {option} a path")


__all__ = ["check_plot_dir", "plot_outputs", "refuse_shared_outputs", "refuse_stdout", "side_file", "tagged_name"]
