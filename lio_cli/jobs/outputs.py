"""Where a run's files go and how they are written: the trajectory plus ``.metrics.json`` and
``.config.yaml`` beside it, each atomically, after every location was checked before the work started."""

from __future__ import annotations

import json
from collections.abc import Iterable
from pathlib import Path

import numpy as np

from ..io.files.atomic import atomic_outputs, check_writable

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


def beside(out: Path, suffix: str) -> Path:
    """``out`` with its suffix replaced by ``suffix`` (``walk.tum`` -> ``walk.metrics.json``)."""
    name = out.name[: -len(out.suffix)] if out.suffix else out.name
    return out.with_name(name + suffix)


def run_outputs(out: Path) -> list[Path]:
    """The files a run writing ``out`` produces: ``out`` itself, its metrics and its resolved config."""
    return [out, beside(out, ".metrics.json"), beside(out, ".config.yaml")]


def check_outputs(out: Path, force: bool, inputs: Iterable[Path] = ()) -> None:
    """Every file of ``run_outputs(out)`` may be written and is none of ``inputs`` (before any work)."""
    inputs = list(inputs)
    for path in run_outputs(out):
        check_writable(path, force, inputs)


def json_text(obj) -> str:
    return json.dumps(obj, indent=2, default=_json_default) + "\n"


def _json_default(o):
    if isinstance(o, np.integer):
        return int(o)
    if isinstance(o, np.floating):
        return float(o)
    if isinstance(o, np.ndarray):
        return o.tolist()
    if isinstance(o, Path):
        return str(o)
    raise TypeError(f"not JSON serialisable: {type(o).__name__}")


def write_run(out: Path, text: str, config, metrics: dict, force: bool) -> None:
    """Write ``text`` to ``out`` and the resolved ``config`` and ``metrics`` beside it (each atomically)."""
    from ..config import dump_model  # pydantic: loaded only by the commands that write a config

    traj, metrics_path, config_path = run_outputs(out)
    with atomic_outputs([traj, config_path, metrics_path], force) as (tmp, config_tmp, metrics_tmp):
        tmp.write_text(text)
        config_tmp.write_text(dump_model(config))
        metrics_tmp.write_text(json_text(metrics))
