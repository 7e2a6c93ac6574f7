"""What each command of a batch is: its configuration model, the job it runs, the files it writes in a run's
folder, and the few metrics the summary shows.

The job and the files are the single command's (``jobs.odom``, ``jobs.fuse``, ``jobs.deskew``, written by the
same writers), so a run's trajectory and ``.config.yaml`` are byte for byte what ``lio odom LOG -o FILE``
writes. Nothing here prints.
"""

from __future__ import annotations

import math
from pathlib import Path
from typing import Any

from pydantic import BaseModel

from ..config import load_config, with_overrides
from ..config.calibrate import CalibrateConfig
from ..config.deskew import DeskewConfig
from ..config.fuse import FuseConfig
from ..config.odom import OdomConfig
from ..errors import ConfigError, InputError
from ..evaluation.scoring import score
from ..io.logs.detect import detect_format
from ..io.sensors.sources import load_ground_truth
from ..io.logs.writer import FILE_SUFFIXES
from ..model.trajectory import Trajectory
from .manifest import RunSpec

CONFIGS: dict[str, type[BaseModel]] = {"odom": OdomConfig, "fuse": FuseConfig, "deskew": DeskewConfig,
                                        "calibrate": CalibrateConfig}
STEMS = {"odom": "odom", "fuse": "fused", "deskew": "deskewed", "calibrate": "calib"}  # a run's files: STEM.tum, STEM.metrics.json...
KEY_METRICS = ("scans_total", "scans_used", "poses", "span_s", "real_time_factor",
               "ate_m", "ate_deg", "rpe_m", "final_error_m")


def resolve_config(spec: RunSpec) -> BaseModel:
    """The run's configuration: the command's defaults, its ``config`` file, its ``calib`` file, its options."""
    if spec.gt is not None and spec.command in ("deskew", "calibrate"):
        raise ConfigError(f"{spec.where}: gt: {spec.command} writes no trajectory to score; drop gt")
    model = CONFIGS[spec.command]
    # a calibration given to calibrate is the reference it compares with (its --calib), elsewhere the extrinsics
    try:
        cfg = load_config(model, spec.config, spec.calib, "prior" if spec.command == "calibrate" else "calibration")
    except (ConfigError, InputError) as err:  # a missing or bad file: say which run of which manifest names it
        raise type(err)(f"{spec.where}: {err}") from err
    return with_overrides(cfg, spec.options, f"{spec.where}: options")


def metrics_file(command: str) -> str:
    return f"{STEMS[command]}.metrics.json"


def _deskew_out(folder: Path, log: Path, cfg: DeskewConfig) -> Path:
    """The output log of a deskew run: a file with the suffix of its format (the input's unless asked: a folder
    of split ROS 1 bags gives a .bag), a folder for a ROS 2 bag."""
    fmt = cfg.output_format or cfg.input.format
    if fmt is None:
        try:
            fmt, _ = detect_format(Path(log))
        except InputError:  # the run itself says what is wrong with the log
            fmt = None
    suffix = FILE_SUFFIXES.get(fmt or "", "")
    return folder / f"{STEMS['deskew']}{suffix}"


def score_trajectory(ref: Trajectory, gt: str, est: Trajectory) -> dict:
    """ATE/RPE of ``est`` against the ground truth ``ref`` (read from ``gt`` before the run), as ``lio odom --gt``
    scores."""
    return score(Trajectory(ref.stamps_ns, ref.poses, gt), Trajectory(est.stamps_ns, est.poses, "estimate")).to_dict()


def registration_threads(command: str, config: BaseModel) -> int | None:
    """The kiss-icp thread count a run's registrations ask for (None: it registers no scans). kiss-icp fixes
    the count for a whole process at its first registration, so runs asking for different counts each need
    a fresh process (calibrate's 1 is what makes its result repeatable)."""
    if command in ("odom", "calibrate"):
        return config.registration.threads
    if command == "deskew":
        return None if config.trajectory.path is not None else config.odometry.registration.threads
    return None


def run_command(command: str, log: Path, config: BaseModel, gt: str | None, folder: Path) -> dict:
    """Run the command's job on ``log`` and write its files into ``folder``; return its metrics."""
    if command == "odom":
        from ..jobs.odom.job import OdomJob, run_odom
        from ..jobs.outputs import write_odom

        result = run_odom(OdomJob(log, config, gt))
        write_odom(result, folder / f"{STEMS['odom']}.tum", False)
        return result.metrics
    if command == "fuse":
        from ..jobs.fuse.job import FuseJob, run_fuse
        from ..jobs.fuse.outputs import write_fuse

        ref = load_ground_truth(log, gt) if gt is not None else None  # bad input before the run, not after
        run = run_fuse(FuseJob(log, config))
        if ref is not None:
            run.metrics["accuracy"] = score_trajectory(ref, gt, run.trajectory)
        write_fuse(run, folder / f"{STEMS['fuse']}.tum", False)
        return run.metrics
    if command == "calibrate":
        from ..jobs.calibrate.job import CalibrateJob, run_calibrate

        return run_calibrate(CalibrateJob(log, folder / f"{STEMS['calibrate']}.yaml", config)).metrics
    from ..jobs.deskew.job import DeskewJob, run_deskew

    # a batch already keeps every core busy with one log each: no second process per log
    return run_deskew(DeskewJob(log, _deskew_out(folder, log, config), config, helper=False)).metrics


def key_metrics(command: str, metrics: dict) -> dict[str, Any]:
    """The summary's columns of one run (None where the command has no such figure)."""
    out: dict[str, Any] = dict.fromkeys(KEY_METRICS)
    if command == "odom":
        out.update(scans_total=metrics["scans"]["total"], scans_used=metrics["scans"]["used"],
                   span_s=metrics.get("trajectory_span_s"))
    elif command == "fuse":
        out.update(poses=metrics["output"]["poses"])
    elif command == "calibrate":
        pass  # its figures are the calibration itself, in the run's calib.yaml
    else:
        out.update(scans_total=metrics["scans"]["total"], scans_used=metrics["scans"]["deskewed"],
                   span_s=metrics.get("log_duration_s"))
    out["real_time_factor"] = metrics.get("real_time_factor")
    acc = metrics.get("accuracy")
    if acc:
        out.update(ate_m=acc["ate_trans_rmse_m"], ate_deg=acc["ate_rot_rmse_deg"], rpe_m=acc["rpe_trans_rmse_m"],
                   final_error_m=acc["final_error_m"])
    return {k: (round(v, 6) if isinstance(v, float) and math.isfinite(v) else v) for k, v in out.items()}


__all__ = ["CONFIGS", "KEY_METRICS", "STEMS", "key_metrics", "metrics_file", "resolve_config", "run_command",
           "score_trajectory"]
