"""Where a run's files go and how they are written: the main output plus ``NAME.TAG.metrics.json`` and
``NAME.TAG.config.yaml`` beside it (TAG the command's: odom, fuse, deskew, calib; ``side_file``), each
atomically, after every location was checked before the work started."""

from __future__ import annotations

import json
from collections.abc import Iterable
from pathlib import Path

import numpy as np

from ..io.files.atomic import atomic_outputs, check_writable
from ..io.files.output_paths import side_file

LOG_SUFFIXES = (".bag", ".mcap", ".db3")


def log_stem(log: Path) -> str:
    """A log's name without its format suffix (a ROS 2 bag's folder name for its metadata.yaml)."""
    p = Path(log)
    if p.name == "metadata.yaml":
        p = p.parent
    name = p.name
    for suffix in LOG_SUFFIXES:
        name = name.removesuffix(suffix)
    return name or "odom"


def default_output(log: Path, tag: str, suffix: str) -> Path:
    """A command's main output when none is given: LOG-stem.TAG.SUFFIX in the current folder (walk.odom.tum)."""
    return Path(f"{log_stem(log)}.{tag}{suffix}")


def sidecars(out: Path, tag: str) -> tuple[Path, Path]:
    """(metrics, resolved config) that command ``tag`` writes beside ``out``."""
    return side_file(out, tag, ".metrics.json"), side_file(out, tag, ".config.yaml")


def run_outputs(out: Path, tag: str) -> list[Path]:
    """The files a run of command ``tag`` writing ``out`` produces: ``out`` itself, its metrics and its config."""
    return [Path(out), *sidecars(Path(out), tag)]


def check_outputs(out: Path, tag: str, force: bool, inputs: Iterable[Path] = ()) -> None:
    """Every file of ``run_outputs(out, tag)`` may be written and is none of ``inputs`` (before any work)."""
    inputs = list(inputs)
    for path in run_outputs(out, tag):
        check_writable(path, force, inputs)


def json_text(obj) -> str:
    return json.dumps(obj, indent=2, default=_json_default) + "\n"


def _json_default(o):
    if isinstance(o, np.bool_):
        return bool(o)
    if isinstance(o, np.integer):
        return int(o)
    if isinstance(o, np.floating):
        return float(o)
    if isinstance(o, np.ndarray):
        return o.tolist()
    if isinstance(o, Path):
        return str(o)
    raise TypeError(f"not JSON serialisable: {type(o).__name__}")


def write_run(out: Path, tag: str, text: str | Iterable[str], config, metrics: dict, force: bool) -> list[Path]:
    """Write ``text`` (or its parts one after the other) to ``out`` and the resolved ``config`` and ``metrics``
    beside it (each atomically); return the three paths."""
    from ..config import dump_model  # pydantic: loaded only by the commands that write a config

    traj, metrics_path, config_path = run_outputs(out, tag)
    with atomic_outputs([traj, config_path, metrics_path], force) as (tmp, config_tmp, metrics_tmp):
        with tmp.open("w") as f:
            f.writelines([text] if isinstance(text, str) else text)
        config_tmp.write_text(dump_model(config))
        metrics_tmp.write_text(json_text(metrics))
    return [traj, metrics_path, config_path]
