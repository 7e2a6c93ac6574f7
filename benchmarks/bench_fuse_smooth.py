#!/usr/bin/env python3
"""`lio fuse --smooth`: the GTSAM factor graph against the RTS smoother it replaces and the filter under both.

(1) `lio odom` trajectory + IMU (+ wheels), --rate 200: ATE, and RPE over 0.05 s against the odometry
    interpolated linearly (targets: ATE <= the odometry's, RPE <= 0.5x the interpolated odometry's).
(2) IMU + wheels (wheel calibration errors and a slip), 50 Hz output: ATE against wheel dead reckoning.
(3) Consumer GPS (core inputs, no log): fixes at 5 Hz with 3 m horizontal noise, a 30 m slow altitude wander and
    a 20 m multipath jump for 4 s, the covariance saying 3 m / 6 m: horizontal and vertical RMS error (positions
    centred) against GPS alone.
(4) jackal.bag: end point against robot_localization's (1.0206, 3.4292, 0.7419) +-0.138 m.
(6) fuse-sim's consumer GPS (`lio simulate rover --gps-model consumer`): mostly slow horizontal error, altitude
    wander, a multipath jump, a covariance a third of the truth; horizontal and vertical RMS error, centred.
(5) Speed and memory: a planar IMU + wheel log of 100 s and of 400 s through the job, each in its own process:
    log span over CPU seconds, and peak RSS (the log's reading dominates it); then the core alone on simulated
    inputs: how far the peak RSS grows above the inputs' while fusing.

RTS rows: the graph switched off (``lio_cli.core.fuse.graph.applies`` patched), which is what `--smooth` was.

    python benchmarks/bench_fuse_smooth.py                  # every section
    python benchmarks/bench_fuse_smooth.py --sections 3 5
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
import tempfile
import time
from dataclasses import replace
from pathlib import Path

import numpy as np

from bench_fuse import RL_END, RL_TOL_M, REAL_LOGS_CANDIDATES, ate, gt_of, quiet_lio, rpe
from bytecode_cache import use_bytecode_cache

import lio_cli.core.fuse.graph as graph
from lio_cli.config.fuse import FuseConfig
from lio_cli.core.fuse import FuseOptions, GpsSeries, fuse
from lio_cli.geometry import interpolate_poses
from lio_cli.io.files.trajectory import read_tum
from lio_cli.io.sensors.sources import load_trajectory
from lio_cli.jobs.fuse.job import FuseJob, run_fuse
from lio_cli.simulation.fusion_case import simulate_case
from lio_cli.simulation.run import simulate

ROOT = Path(__file__).resolve().parents[1]
KINDS = ("filter", "rts", "graph")


class Rts:
    """`--smooth` as it was: the RTS pass (the graph switched off)."""

    def __enter__(self):
        self.saved = graph.applies
        graph.applies = lambda prep: False

    def __exit__(self, *exc):
        graph.applies = self.saved


def with_kind(kind: str, fn):
    if kind == "rts":
        with Rts():
            return fn()
    return fn()


def fallback(metrics: dict) -> str:
    sm = metrics.get("core", metrics).get("smoother") or {}
    return "" if not sm.get("fallback") else "  (filter kept: " + sm["fallback"] + ")"


def section_odom(work: Path, duration: float, seed: int) -> None:
    print(f"\n(1) lio odom + IMU (+ wheels) -> fuse --rate 200, {duration:.0f} s")
    print(f"{'scenario':<9} {'run':<26} {'ATE m':>8} {'RPE.05 m':>9} {'ATE/odom':>9} {'RPE/interp':>11}")
    for scen in ("handheld", "drive", "corridor"):
        log = work / f"{scen}.bag"
        simulate(scen, log, duration_s=duration, seed=seed, force=True)
        gt = gt_of(log)
        odom = work / f"{scen}_odom.tum"
        if quiet_lio("odom", log, "-o", odom, "--force", "-q") != 0:
            print(f"{scen:<9} lio odom failed")
            continue
        ost, opo = read_tum(odom)
        q = gt.stamps_ns[(gt.stamps_ns >= ost[0]) & (gt.stamps_ns <= ost[-1])]
        o_ate, i_rpe = ate(gt, ost, opo), rpe(gt, q, interpolate_poses(ost, opo, q))
        print(f"{scen:<9} {'odometry / interpolated':<26} {o_ate:>8.4f} {i_rpe:>9.4f}")
        for wheels in ((False, True) if scen != "handheld" else (False,)):
            use = ["--use", "imu:gyro,accel", "--use", "odom"] + (["--use", "wheel"] if wheels else [])
            for kind in KINDS:
                out = work / f"{scen}_{kind}.tum"
                flags = [] if kind == "filter" else ["--smooth"]
                code = with_kind(kind, lambda: quiet_lio("fuse", log, "--odom", odom, "--rate", 200, *use, *flags,
                                                         "-o", out, "--force", "-q"))
                if code != 0:
                    print(f"{'':<9} {kind:<26} failed (exit {code})")
                    continue
                st, po = read_tum(out)
                a, r = ate(gt, st, po), rpe(gt, st, po)
                name = kind + (" + wheels" if wheels else "")
                print(f"{'':<9} {name:<26} {a:>8.4f} {r:>9.4f} {a / o_ate:>9.2f} {r / i_rpe:>11.2f}")


def section_wheels(work: Path, duration: float, seed: int) -> None:
    print(f"\n(2) IMU + wheels (calibration errors, a slip), {duration:.0f} s, 50 Hz")
    print(f"{'scenario':<9} {'run':<26} {'ATE m':>8} {'ATE/DR':>7}")
    for scen in ("planar", "corridor"):
        log = work / f"{scen}_w.bag"
        simulate(scen, log, duration_s=duration, seed=seed, force=True, columns=256 if scen == "corridor" else None)
        gt = gt_of(log)
        dr = load_trajectory(f"{log}:/wheel/odom")
        dr_ate = ate(gt, dr.stamps_ns, dr.poses)
        print(f"{scen:<9} {'wheel dead reckoning':<26} {dr_ate:>8.3f}")
        for est in ("ekf", "planar"):
            for kind in KINDS:
                cfg = FuseConfig(estimator=est, smooth=kind != "filter", rate_hz=50.0)
                run = with_kind(kind, lambda: run_fuse(FuseJob(log, cfg)))
                a = ate(gt, run.trajectory.stamps_ns, run.trajectory.poses)
                print(f"{'':<9} {est + ' ' + kind:<26} {a:>8.3f} {a / dr_ate:>7.2f}{fallback(run.metrics)}")


def consumer_gps(case, rng, h=3.0, wander=30.0, jump=20.0) -> tuple[GpsSeries, np.ndarray]:
    """Fixes at the case's GPS stamps: ``h`` m horizontal noise, a slow ``wander`` m altitude swing, ``jump`` m
    east for 4 s at 60 % of the run; covariance ``h`` horizontal, ``2 h`` vertical (optimistic in altitude)."""
    g = case.inputs.gps
    t = (g.stamps_ns - g.stamps_ns[0]) * 1e-9
    truth = interpolate_poses(case.truth_stamps_ns, case.truth_poses, g.stamps_ns)[:, :3, 3]
    z = truth.copy()
    z[:, :2] += rng.normal(0, h, (len(t), 2))
    z[:, 2] += wander * np.sin(2 * np.pi * 0.7 * t / t[-1]) + rng.normal(0, 1.0, len(t))
    z[(t > 0.6 * t[-1]) & (t < 0.6 * t[-1] + 4), 0] += jump
    cov = np.broadcast_to(np.diag([h**2, h**2, (2 * h) ** 2]), (len(t), 3, 3)).copy()
    return GpsSeries(g.stamps_ns, z, cov, np.ones(len(t), bool)), truth


def centred_errors(case, stamps, poses) -> tuple[float, float]:
    tr = interpolate_poses(case.truth_stamps_ns, case.truth_poses, stamps)[:, :3, 3]
    d = (poses[:, :3, 3] - poses[:, :3, 3].mean(0)) - (tr - tr.mean(0))
    return float(np.sqrt(np.mean(np.sum(d[:, :2] ** 2, 1)))), float(np.sqrt(np.mean(d[:, 2] ** 2)))


def section_gps(duration: float) -> None:
    print(f"\n(3) consumer GPS (3 m, 30 m altitude wander, 20 m jump), IMU + wheels, {duration:.0f} s, 20 Hz")
    print(f"{'scenario':<9} {'run':<14} {'horiz m':>8} {'vert m':>7} {'cpu s':>6}")
    for scen in ("planar", "drive", "corridor"):
        case = simulate_case(scen, duration, seed=3, gps_sigma_m=0.1)
        gps, truth = consumer_gps(case, np.random.default_rng(1))
        hz, vt = centred_errors(case, gps.stamps_ns, _at(gps.position_enu_m))
        print(f"{scen:<9} {'GPS alone':<14} {hz:>8.2f} {vt:>7.2f}")
        inp = replace(case.inputs, gps=gps)
        for kind in KINDS:
            c0 = time.process_time()
            res = with_kind(kind, lambda: fuse(inp, FuseOptions(smooth=kind != "filter", rate_hz=20.0)))
            cpu = time.process_time() - c0
            hz, vt = centred_errors(case, res.stamps_ns, res.poses)
            print(f"{'':<9} {kind:<14} {hz:>8.2f} {vt:>7.2f} {cpu:>6.2f}{fallback(res.info)}")


def _at(p: np.ndarray) -> np.ndarray:
    T = np.zeros((len(p), 4, 4))
    T[:, :3, 3] = p
    return T


def section_rover(work: Path, duration: float, seed: int) -> None:
    print(f"\n(6) lio simulate rover --gps --gps-model consumer --no-lidar, {duration:.0f} s, defaults, 20 Hz")
    print(f"{'run':<8} {'horiz m':>8} {'vert m':>7} {'cpu s':>6}")
    log = work / "rover.bag"
    simulate("rover", log, duration_s=duration, seed=seed, force=True, gps=True, gps_model="consumer", lidar=False)
    gt = gt_of(log)
    for kind in KINDS:
        c0 = time.process_time()
        run = with_kind(kind, lambda: run_fuse(FuseJob(log, FuseConfig(smooth=kind != "filter", rate_hz=20.0))))
        cpu = time.process_time() - c0
        tr = interpolate_poses(gt.stamps_ns, gt.poses, run.trajectory.stamps_ns)
        case = type("Truth", (), {"truth_stamps_ns": run.trajectory.stamps_ns, "truth_poses": tr})
        hz, vt = centred_errors(case, run.trajectory.stamps_ns, run.trajectory.poses)
        print(f"{kind:<8} {hz:>8.2f} {vt:>7.2f} {cpu:>6.2f}{fallback(run.metrics)}")


def section_jackal(real: Path) -> None:
    print("\n(4) jackal.bag end point (robot_localization: "
          f"({RL_END[0]}, {RL_END[1]}, {RL_END[2]}) +-{RL_TOL_M} m)")
    jackal = real / "jackal_imu_wheel" / "jackal.bag"
    if not jackal.exists():
        print(f"  {jackal} not found: skipped")
        return
    for est in ("ekf", "planar"):
        for kind in KINDS:
            c0 = time.process_time()
            run = with_kind(kind, lambda: run_fuse(FuseJob(jackal, FuseConfig(estimator=est, smooth=kind != "filter"))))
            cpu = time.process_time() - c0
            end = run.trajectory.positions[-1]
            d = float(np.linalg.norm(end - RL_END))
            print(f"  {est + ' ' + kind:<14} end ({end[0]:.3f}, {end[1]:.3f}, {end[2]:.3f})  diff {d:.3f} m "
                  f"{'inside' if d <= RL_TOL_M else 'OUTSIDE'}  cpu {cpu:.2f} s{fallback(run.metrics)}")


CHILD = """
import json, resource, sys, time
sys.path.insert(0, {root!r})
import lio_cli.core.fuse.graph as graph
from lio_cli.config.fuse import FuseConfig
from lio_cli.jobs.fuse.job import FuseJob, run_fuse
if {kind!r} == "rts":
    graph.applies = lambda prep: False
base = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
c0 = time.process_time()
run = run_fuse(FuseJob({log!r}, FuseConfig(smooth={kind!r} != "filter", rate_hz=50.0)))
cpu = time.process_time() - c0
rss = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
print(json.dumps({{"cpu": cpu, "span": run.metrics["log_span_s"], "rss_mb": rss / 1024,
                  "base_mb": base / 1024, "chunks": (run.metrics["core"].get("smoother") or {{}}).get("chunks")}}))
"""


CORE_CHILD = """
import json, resource, sys, time
sys.path.insert(0, {root!r})
import lio_cli.core.fuse.graph as graph
from lio_cli.core.fuse import FuseOptions, fuse
from lio_cli.simulation.fusion_case import simulate_case
if {kind!r} == "rts":
    graph.applies = lambda prep: False
case = simulate_case("planar", {dur!r}, seed=3)
base = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
c0 = time.process_time()
res = fuse(case.inputs, FuseOptions(smooth={kind!r} != "filter", rate_hz=50.0))
cpu = time.process_time() - c0
print(json.dumps({{"cpu": cpu, "grew_mb": (resource.getrusage(resource.RUSAGE_SELF).ru_maxrss - base) / 1024,
                  "chunks": (res.info.get("smoother") or {{}}).get("chunks")}}))
"""


def section_speed(work: Path, seed: int) -> None:
    print("\n(5) speed and memory: planar IMU + wheels through the job, 50 Hz output, one process per run")
    print(f"{'log':<6} {'run':<8} {'cpu s':>7} {'x real time':>12} {'peak RSS MB':>12} {'chunks':>7}")
    for dur in (100.0, 400.0):
        log = work / f"speed_{int(dur)}.bag"
        simulate("planar", log, duration_s=dur, seed=seed, force=True)
        for kind in KINDS:
            code = CHILD.format(root=str(ROOT), kind=kind, log=str(log))
            out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
            r = json.loads(out.stdout.strip().splitlines()[-1])
            print(f"{dur:>4.0f} s {kind:<8} {r['cpu']:>7.2f} {r['span'] / r['cpu']:>12.0f} {r['rss_mb']:>12.0f} "
                  f"{r['chunks'] if r['chunks'] else '':>7}")
    print("the core alone (simulated inputs in memory, 50 Hz output): CPU, and how far the peak RSS grew above the "
          "inputs' while fusing")
    print(f"{'log':<6} {'run':<8} {'cpu s':>7} {'x real time':>12} {'RSS growth MB':>14} {'chunks':>7}")
    for dur in (100.0, 400.0):
        for kind in KINDS:
            code = CORE_CHILD.format(root=str(ROOT), kind=kind, dur=dur)
            out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
            r = json.loads(out.stdout.strip().splitlines()[-1])
            print(f"{dur:>4.0f} s {kind:<8} {r['cpu']:>7.2f} {dur / r['cpu']:>12.0f} {r['grew_mb']:>14.0f} "
                  f"{r['chunks'] if r['chunks'] else '':>7}")


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--duration", type=float, default=30.0, help="simulated seconds, sections 1 and 2")
    ap.add_argument("--gps-duration", type=float, default=120.0, help="seconds, section 3")
    ap.add_argument("--seed", type=int, default=1)
    ap.add_argument("--sections", type=int, nargs="*", default=[1, 2, 3, 4, 5, 6])
    ap.add_argument("--real-logs", type=Path, default=next((p for p in REAL_LOGS_CANDIDATES if p.exists()),
                                                            REAL_LOGS_CANDIDATES[0]))
    args = ap.parse_args()
    use_bytecode_cache()
    with tempfile.TemporaryDirectory(prefix="bench_fuse_smooth_") as tmp:
        work = Path(tmp)
        if 1 in args.sections:
            section_odom(work, args.duration, args.seed)
        if 2 in args.sections:
            section_wheels(work, args.duration, args.seed)
        if 3 in args.sections:
            section_gps(args.gps_duration)
        if 4 in args.sections:
            section_jackal(args.real_logs)
        if 5 in args.sections:
            section_speed(work, args.seed)
        if 6 in args.sections:
            section_rover(work, args.gps_duration, args.seed)
    return 0


if __name__ == "__main__":
    sys.exit(main())
