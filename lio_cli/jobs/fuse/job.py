"""The ``fuse`` job: read a log's IMU, wheel odometry, GPS and an odometry trajectory, fuse them with the
estimation core (``core.fuse``) into one trajectory of the base frame, gather metrics.

``FuseJob`` (log + the whole configuration) is all a run needs; ``run_fuse`` returns the trajectory (the first
output pose at the origin of a z-up world), per-pose covariances when asked, the resolved configuration (topics,
base frame, wheel twist frame and the measurement selection filled in: written beside the outputs, it repeats
the run exactly), metrics and notes; ``score_fuse`` adds the accuracy against a ground truth. Nothing is printed
or written here (``outputs.write_fuse`` writes).
"""

from __future__ import annotations

import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from ...config import with_overrides
from ...config.fuse import FuseConfig
from ...core.fuse import (COVARIANCE_LAYOUT, NOTE_REASONS, REJECT_REASONS, FuseOptions, FuseResult,
                          NoiseOptions, whole_log_options)
from ...evaluation.scoring import Score
from ...gc_pause import cyclic_gc_paused
from ...io.logs.reader import open_log
from ...model.trajectory import Trajectory
from ..contract import score_into
from .chunks import fuse_chunked
from .memory import MemoryPlan, plan
from .clocks import clock_report
from .inputs import FuseSources, gather_sources
from .summary import source_summary

Progress = Callable[[int, int | None], None]  # (work done, total work) in message-sized units


@dataclass(frozen=True)
class FuseJob:
    """Everything one ``lio fuse`` run needs; ``covariance``: compute the per-pose covariance (for --cov)."""

    log: Path
    config: FuseConfig = field(default_factory=FuseConfig)
    covariance: bool = False


@dataclass
class FuseRun:
    trajectory: Trajectory  # T_world_base at the output stamps, first pose at the origin
    covariances: np.ndarray | None  # (N,6,6) in COVARIANCE_LAYOUT order
    velocities_mps: np.ndarray | None  # (N,3) world frame
    config: FuseConfig  # resolved: repeats the run
    metrics: dict
    notes: list[str]
    roles: dict[str, dict]
    sources: FuseSources  # what was fused (for plots)
    score: Score | None = None  # set by ``score_fuse``


def core_options(cfg: FuseConfig, use: dict[str, list[str]] | None, covariance: bool = False) -> FuseOptions:
    """The estimation core's options for a configuration and a resolved measurement selection."""
    return FuseOptions(
        estimator=cfg.estimator, smooth=cfg.smooth,
        use=None if use is None else {s: set(m) for s, m in use.items()},
        default_use=use is not None and cfg.use is None,  # the default selection, resolved
        weigh_wheel_yaw=None if use is None and cfg.weigh_wheel_yaw is None else weighs_wheel_yaw(cfg),
        noise=NoiseOptions(**cfg.noise.model_dump()), rate_hz=cfg.rate_hz,
        gate_probability=cfg.gate_probability, gate_max_rejects=cfg.gate_max_rejects, gap_periods=cfg.gap_periods,
        min_gap_ns=int(round(cfg.min_gap_s * 1e9)), snap_ns=int(round(cfg.snap_s * 1e9)),
        gravity_mps2=cfg.gravity_mps2, standing_window_ns=int(round(cfg.standing_window_s * 1e9)),
        alpha_odom=cfg.alpha_odom, alpha_orientation=cfg.alpha_orientation, alpha_gps=cfg.alpha_gps,
        want_covariance=covariance,
    )


def weighs_wheel_yaw(cfg: FuseConfig) -> bool:
    """Whether the run weighs the wheels' yaw rate against the gyro: as configured, else without a ``use`` (None
    in the core's options where neither is given: the core's own default, the same)."""
    return cfg.use is None if cfg.weigh_wheel_yaw is None else cfg.weigh_wheel_yaw


def run_fuse(job: FuseJob, progress: Progress | None = None) -> FuseRun:
    """Fuse the sources of ``job.log`` (see the module docstring)."""
    with cyclic_gc_paused():  # reading and filtering allocate many small lists, none in a cycle
        return _run_fuse(job, progress)


def _run_fuse(job: FuseJob, progress: Progress | None) -> FuseRun:
    cfg = job.config
    core_options(cfg, cfg.use).validate()  # a bad option is refused before the log is opened
    t_wall, t_cpu = time.perf_counter(), time.process_time()
    with open_log(job.log, cfg.input.format) as reader:
        total = sum(reader.topics[t].count for t in reader.topics) or 1

        def read_step(n: int) -> None:
            if progress:
                progress(min(n, total), 2 * total)

        sources = gather_sources(reader, cfg, read_step)
        fmt = reader.format
    clocks, clock_notes = clock_report(sources.inputs, cfg)
    sources.notes.extend(clock_notes)
    t_read = time.perf_counter() - t_wall
    options = core_options(cfg, sources.use, job.covariance)
    choice, options = whole_log_options(sources.inputs, options)  # once for the whole log: every chunk the same
    if options.use is not None:  # as the estimator took it (odometry as increments beside the planar filter)
        sources.use = {s: sorted(m) for s, m in options.use.items()}
    memory = plan(sources.inputs, options, sources.use, cfg.max_memory_mb)

    def fuse_step(k: int, n: int) -> None:
        if progress:
            progress(total + total * k // n, 2 * total)

    t_fuse = time.perf_counter()
    result, chunks = fuse_chunked(sources.inputs, options, memory, fuse_step)
    t_fuse = time.perf_counter() - t_fuse
    _add_gps_drops(result, sources)
    _add_orientation_drop(result, sources)
    result.info.update(estimator_reason=choice.reason, estimator_evidence=choice.evidence)
    resolved = with_overrides(cfg, {
        "input.imu_topic": _topic(sources, "imu"), "input.wheel_topic": _topic(sources, "wheel"),
        "input.gps_topic": _topic(sources, "gps"), "input.base_frame": sources.base_frame,
        "input.wheel_twist_frame": sources.wheel_twist_frame,
        "input.gps_origin": _gps_origin(sources), "use": sources.use, "weigh_wheel_yaw": options.weigh_wheel_yaw,
        "estimator": choice.name,
    }, "resolved configuration")
    traj = Trajectory(result.stamps_ns, result.poses, f"{job.log}:fuse", "fuse")
    wall, cpu = time.perf_counter() - t_wall, time.process_time() - t_cpu
    metrics = _metrics(job, fmt, sources, result, memory, chunks, {"read": t_read, "fuse": t_fuse, "total": wall,
                                                                  "cpu": cpu})
    if clocks:
        metrics["clocks"] = clocks
    notes = list(sources.notes) + [n for n in result.info.get("notes", []) if n not in sources.notes]
    metrics["notes"] = notes
    return FuseRun(traj, result.covariances if job.covariance else None, result.velocities_mps, resolved, metrics,
                   notes, sources.roles, sources)


def score_fuse(run: FuseRun, reference: Trajectory) -> None:
    """ATE/RPE against ``reference`` (``contract.load_reference``, read before the run) into ``run``."""
    score_into(run, reference, "estimate")


def _topic(sources: FuseSources, src: str) -> str | None:
    return sources.roles.get(src, {}).get("topic")


def _gps_origin(sources: FuseSources) -> list[float] | None:
    if sources.gps is None:
        return None
    o = sources.gps.origin
    return [float(o.lat_deg), float(o.lon_deg), float(o.alt_m)]


def _add_gps_drops(result: FuseResult, sources: FuseSources) -> None:
    """Fixes the GPS reader dropped before the core saw them count in the GPS source's report."""
    g, rep = sources.gps, result.reports.get("gps")
    if g is None or rep is None:
        return
    rep.received += g.dropped
    rep.reject("no_fix", g.no_fix)
    rep.reject("nan", g.bad_coordinates)
    rep.reject("duplicate_stamp", g.bad_stamps)


def _add_orientation_drop(result: FuseResult, sources: FuseSources) -> None:
    """The IMU orientations left out for not following the gyro count in the IMU source's report."""
    check, rep = sources.checks.get("imu_orientation"), result.reports.get("imu")
    if check is not None and rep is not None:
        rep.reject("orientation_unfollowed", check["samples"])


def _smoother(asked: bool, info: dict | None) -> dict:
    """Which smoother ran (``factor_graph``, ``rts`` or none) and why, for metrics and the printed summary."""
    if not asked:
        return {"kind": None, "why": "--no-smooth: the filter alone"}
    if not info:
        return {"kind": None, "why": "no smoother for this run"}
    kind, refused = info.get("kind"), info.get("fallback")
    if kind != "factor_graph":
        return {"kind": kind, "why": info.get("why", "")}
    if refused is None:
        out = {"kind": kind, "why": "over the whole log, with the accelerometer"}
        return {**out, "wheel": info["wheel"]} if info.get("wheel") else out
    kept = info.get("kept", "filter")  # the chosen filter's own result: its RTS pass, or the filter alone
    return {"kind": kept if kept == "rts" else None,
            "why": f"the factor graph refused by its guard ({refused}); the filter's trajectory"
                   + (" smoothed by RTS" if kept == "rts" else "")}


def _span_s(sources: FuseSources) -> float:
    st = [s.stamps_ns for s in sources.inputs.present().values()]
    return (max(int(s.max()) for s in st) - min(int(s.min()) for s in st)) * 1e-9


def _metrics(job: FuseJob, fmt: str, sources: FuseSources, result: FuseResult, memory: MemoryPlan,
             chunks: list[dict], times: dict[str, float]) -> dict:
    cfg = job.config
    span = _span_s(sources)
    reports = result.reports
    per_source = {}
    for src, role in sources.roles.items():
        rep = reports.get(src)
        entry = {**role, "measurements": sources.use.get(src, [])}
        if rep is not None:
            entry.update(received=rep.received, updates=rep.updates, predictions=rep.predictions,
                         updates_by_kind=rep.by_kind,
                         rejected={k: {"count": v, "why": REJECT_REASONS.get(k, k)} for k, v in rep.rejected.items()},
                         handled={k: {"count": v, "what": NOTE_REASONS.get(k, k)} for k, v in rep.notes.items()},
                         summary=source_summary(src, rep.updates, rep.predictions, rep.by_kind, rep.rejected,
                                                rep.notes))
        else:
            entry["unused"] = "no measurement of this source selected"
        per_source[src] = entry
    stamps = result.stamps_ns
    out = {
        "log": str(job.log),
        "format": fmt,
        "sources": per_source,
        "sources_used": sorted(reports),
        "updates": {s: r.updates for s, r in reports.items()},
        "rejected": {s: dict(r.rejected) for s, r in reports.items()},
        "base_frame": sources.base_frame,
        "extrinsics": sources.extrinsics,
        "estimator": result.estimator,
        "estimator_reason": result.info.get("estimator_reason"),
        "smoothed": result.smoothed,
        "smoother": _smoother(cfg.smooth, result.info.get("smoother")),
        "output": {"frame": "base", "poses": len(stamps),
                   "stamps": f"{cfg.rate_hz:g} Hz" if cfg.rate_hz else _imu_stamps(result.info)
                   if "imu" in sources.use else "every wheel/odometry message",
                   "first_ns": int(stamps[0]) if len(stamps) else None, "last_ns": int(stamps[-1]) if len(stamps) else None,
                   "world": "z up; the first pose at the origin; heading " + str(result.info.get("world_yaw_from", "start")),
                   "covariance_layout": list(COVARIANCE_LAYOUT) if job.covariance else None},
        "start": result.info.get("start"),
        "core": result.summary(),
        "memory": memory.to_dict(),
        "time_s": {k: round(v, 4) for k, v in times.items()},
        "log_span_s": round(span, 3),
        "real_time_factor": round(span / times["total"], 1) if times["total"] > 0 else None,
        "real_time_factor_cpu": round(span / times["cpu"], 1) if times["cpu"] > 0 else None,
    }
    if sources.gps is not None:
        out["gps"] = sources.gps.summary()
    if "imu_orientation" in sources.checks:
        out["imu_orientation_check"] = sources.checks["imu_orientation"]
    if chunks:
        out["chunks"] = chunks
    return out


__all__ = ["FuseJob", "FuseRun", "Progress", "core_options", "run_fuse", "score_fuse"]


def _imu_stamps(info: dict) -> str:
    """The default output stamps: the IMU's, and inside its gaps the wheels' or odometry's."""
    n = info.get("outputs_in_gyro_gaps", 0)
    return "every IMU sample (exact stamps)" + (f" and {n} wheel/odometry stamps inside gyro gaps" if n else "")
