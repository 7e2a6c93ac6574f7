"""The commands a batch runs: a table over the single commands' ``Command`` records (``jobs.contract``).

A run is the single command's job, run, score and write (the same functions ``lio odom LOG -o FILE`` calls), so
a run's trajectory and ``.config.yaml`` are byte for byte the single command's. Nothing here prints.
"""

from __future__ import annotations

import math
from pathlib import Path
from typing import Any

from pydantic import BaseModel

from ..config import load_config, with_overrides
from ..errors import ConfigError, InputError
from ..jobs import calibrate, deskew, fuse, odom
from ..jobs.contract import Command, load_reference
from .manifest import RunSpec

COMMANDS: dict[str, Command] = {c.name: c for c in (odom.COMMAND, fuse.COMMAND, deskew.COMMAND, calibrate.COMMAND)}
KEY_METRICS = ("scans_total", "scans_used", "poses", "span_s", "real_time_factor",
               "ate_m", "ate_deg", "rpe_m", "final_error_m")


def resolve_config(spec: RunSpec) -> BaseModel:
    """The run's configuration: the command's defaults, its ``config`` file, its ``calib`` file, its options."""
    command = COMMANDS[spec.command]
    if spec.gt is not None and command.score is None:
        raise ConfigError(f"{spec.where}: gt: {spec.command} writes no trajectory to score; drop gt")
    try:
        cfg = load_config(command.config, spec.config, spec.calib, command.calibration_field)
    except (ConfigError, InputError) as err:  # a missing or bad file: say which run of which manifest names it
        raise type(err)(f"{spec.where}: {err}") from err
    return with_overrides(cfg, spec.options, f"{spec.where}: options")


def metrics_file(command: str) -> str:
    return COMMANDS[command].metrics_file()


def registration_threads(command: str, config: BaseModel) -> int | None:
    """The kiss-icp thread count a run's registrations ask for (None: it registers no scans). kiss-icp fixes
    the count for a whole process at its first registration, so runs asking for different counts each need
    a fresh process (calibrate's 1 is what makes its result repeatable)."""
    return COMMANDS[command].threads(config)


def run_command(command: str, log: Path, config: BaseModel, gt: str | None, folder: Path) -> dict:
    """Run the command's job on ``log``, score it against ``gt`` when given, write its files into ``folder``;
    return its metrics."""
    cmd = COMMANDS[command]
    reference = load_reference(log, gt) if gt is not None else None
    out = cmd.output(folder, log, config)
    result = cmd.run(cmd.job(log, config, out))
    if reference is not None:
        cmd.score(result, reference)
    cmd.write(result, out, False)
    return result.metrics


def key_metrics(command: str, metrics: dict) -> dict[str, Any]:
    """The summary's columns of one run (None where the command has no such figure)."""
    out: dict[str, Any] = dict.fromkeys(KEY_METRICS)
    out.update(COMMANDS[command].key_metrics(metrics))
    out["real_time_factor"] = metrics.get("real_time_factor")
    acc = metrics.get("accuracy")
    if acc:
        out.update(ate_m=acc["ate_trans_rmse_m"], ate_deg=acc["ate_rot_rmse_deg"], rpe_m=acc["rpe_trans_rmse_m"],
                   final_error_m=acc["final_error_m"])
    return {k: (round(v, 6) if isinstance(v, float) and math.isfinite(v) else v) for k, v in out.items()}


__all__ = ["COMMANDS", "KEY_METRICS", "key_metrics", "metrics_file", "registration_threads", "resolve_config",
           "run_command"]
