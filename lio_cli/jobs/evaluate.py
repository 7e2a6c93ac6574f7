"""The evaluate job: load a reference and estimates from any trajectory source, score each, group statistics.

``EvaluateJob`` holds everything a ``lio evaluate`` run needs (picklable); ``run_evaluate`` returns the results,
the report the CLI prints as JSON or writes beside plots, and the notes and warnings for people, without printing.
"""

from __future__ import annotations

import time
from dataclasses import asdict, dataclass, field, replace
from pathlib import Path

import numpy as np

from ..errors import ConfigError, InputError
from ..evaluation import EvalOptions, EvalResult, Trajectory, evaluate
from ..evaluation.alignment import line_spread

FAR_ORIGIN_M = 20_000.0  # GPS fixes farther than this from the ENU origin get a warning
# se3/sim3 on reference positions whose spread across their main direction is below this fraction of the spread
# along it (a straight drive, a corridor) get a warning: the rotation about that line is barely determined
LINE_LIKE_RATIO = 0.05


@dataclass(frozen=True)
class EvaluateJob:
    """A reference, estimates (``PATH``, ``LOG:/topic``, ``LOG:tf:a.b``), pairing/alignment/RPE options and groups.

    ``groups`` are ``evaluation.groups.Group`` (two runs each at least); ``ungrouped`` the estimates a
    ``--group-by`` pattern left out. ``t_max_diff_s`` is kept as given for the report (``options`` holds ns).
    """

    gt: str
    estimates: tuple[str, ...]
    options: EvalOptions
    t_max_diff_s: float = 0.01
    gt_topic: str | None = None
    times: Path | None = None
    rate_hz: float | None = None
    gt_stamp_unit: str = "s"
    est_stamp_unit: str = "s"
    origin: tuple[float, float, float] | None = None
    groups: tuple = ()
    ungrouped: tuple[str, ...] = ()


@dataclass
class EvaluateResult:
    reference: object  # the loaded reference (io.sources' trajectory, with kind, gps, position_only)
    loaded: list  # the loaded estimates, in job order
    results: list[EvalResult]
    group_stats: list | None
    report: dict
    notes: list[str] = field(default_factory=list)
    warnings: list[str] = field(default_factory=list)


def run_evaluate(job: EvaluateJob) -> EvaluateResult:
    from ..io.sensors.sources import load_trajectory

    t_start = time.perf_counter()
    opts = job.options
    gt_traj = load_trajectory(job.gt, topic=job.gt_topic, times=job.times, rate_hz=job.rate_hz,
                              stamp_unit=job.gt_stamp_unit, origin=job.origin, stamp_options=True)
    ref = Trajectory(gt_traj.stamps_ns, gt_traj.poses, job.gt)
    # a GPS estimate shares the reference's ENU origin, so --align none compares like with like
    est_origin = job.origin or (gt_traj.gps.origin if gt_traj.gps is not None else None)
    loaded_all = []
    for spec in job.estimates:
        loaded = load_trajectory(spec, times=job.times, rate_hz=job.rate_hz, stamp_unit=job.est_stamp_unit,
                                 origin=est_origin, stamp_options=True)
        if loaded.kind == "kitti" and gt_traj.kind == "kitti" and len(loaded) != len(gt_traj):
            raise InputError(
                f"{spec}: {len(loaded)} KITTI poses but the ground truth {job.gt} has {len(gt_traj)}; KITTI pose "
                f"files pair line by line and must have the same length"
            )
        loaded_all.append(loaded)
    if job.origin is not None and not any(t.position_only for t in (gt_traj, *loaded_all)):
        raise ConfigError(f"--origin applies to GPS (NavSatFix) topics, and neither {job.gt} nor an estimate is one")
    results: list[EvalResult] = []
    for spec, loaded in zip(job.estimates, loaded_all):
        o = replace(opts, translation_only=True) if gt_traj.position_only or loaded.position_only else opts
        results.append(evaluate(ref, Trajectory(loaded.stamps_ns, loaded.poses, spec), o))
    group_stats = None
    if job.groups:
        from ..evaluation.groups import group_statistics

        group_stats = group_statistics(list(job.groups), {r.name: r.flat_metrics() for r in results})

    report = {
        "reference": {"name": job.gt, "poses": len(ref), "kind": gt_traj.kind, "position_only": gt_traj.position_only,
                      **({"gps": gt_traj.gps.summary()} if gt_traj.gps is not None else {})},
        "estimates": [{**r.summary(), **({"gps": t.gps.summary()} if t.gps is not None else {})}
                      for r, t in zip(results, loaded_all)],
        "metrics": [{"estimate": r.name, **r.flat_metrics()} for r in results],
        "options": {**asdict(opts), "t_max_diff_s": job.t_max_diff_s, "t_offset_s": opts.offset_ns / 1e9},
        "elapsed_s": round(time.perf_counter() - t_start, 4),
    }
    out = EvaluateResult(gt_traj, loaded_all, results, group_stats, report)
    if group_stats is not None:
        report["groups"] = [g.summary() for g in group_stats]
        report["ungrouped"] = list(job.ungrouped)
        if job.ungrouped:
            out.notes.append(f"--group-by left out: {', '.join(job.ungrouped)}")
    for t in (gt_traj, *loaded_all):
        if t.gps is not None:
            out.notes.append(t.gps.describe())
            if t.gps.farthest_m > FAR_ORIGIN_M:
                out.warnings.append(
                    f"{t.name}: fixes lie up to {t.gps.farthest_m / 1e3:.0f} km from the ENU origin, whose axes "
                    f"tilt by {np.rad2deg(t.gps.farthest_m / 6.371e6):.2g} deg there; is --origin right?")
    for r in results:
        line = _line_like(r)
        if line is not None:
            across, along = line
            ape_rot = r.stats["ape"]["rot"]["rmse"]
            seen = f" (APE rotation {ape_rot:.3g} deg here)" if ape_rot is not None else ""
            out.warnings.append(
                f"{r.name}: --align {r.options.align}: the reference positions it fits lie nearly on a line "
                f"({across:.3g} m across it against {along:.3g} m along, std): the rotation about that line is "
                f"barely determined and can add rotation error the estimate does not have{seen}; "
                f"--align posyaw fits the yaw only")
        if r.offset is not None and r.offset.note:
            out.warnings.append(f"{r.name}: --estimate-offset: {r.offset.note}")
    return out


def _line_like(r: EvalResult) -> tuple[float, float] | None:
    """(std across, std along) of the reference positions an se3/sim3 alignment fitted when they lie nearly on
    a line (Umeyama then picks the rotation about it from the estimate's errors), else None."""
    if r.options.align not in ("se3", "sim3") or r.alignment.n_used < 3:
        return None
    across, along = line_spread(r.association.ref.poses[: r.alignment.n_used, :3, 3])
    return (across, along) if across < LINE_LIKE_RATIO * along else None
