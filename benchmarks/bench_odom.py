#!/usr/bin/env python3
"""Accuracy and cost of `lio odom` against kiss-icp (LiDAR-only) and RKO-LIO (LiDAR-inertial), per kind of log.

Simulates each scenario once with `lio simulate` (ROS 1 bag, the format all three tools read) and runs the
pipelines on the same log, each in its own process. lio and RKO-LIO run ``--repeats`` times each, alternating
(lio, RKO-LIO, lio, ...), so both see the same load; the median run of each is reported. CPU time (user + system
over all threads) is what counts on a shared, loaded machine: wall time follows the load of other processes,
CPU time much less so. Every trajectory of the base frame is evaluated against the exact ground truth with lio's
evaluation code (evo's APE/RPE definitions): ATE = APE translation RMSE after SE(3) alignment, RPE = translation
RMSE over 10 m segments. kiss-icp's poses (LiDAR frame) are moved to the base frame with the true extrinsic.

A second table gives lio's ms per scan per stage (from its metrics.json: totals over the used scans, and the
median registration), and ``--long`` compares a 10-minute log with a 1-minute one: peak RSS (flat) and CPU per
scan (linear cost).

RKO-LIO is installed into a scratch venv (`pip install rko-lio rosbags`) unless --rko points at one.
Neither peer reads a 2D LaserScan, so `planar` runs lio alone.

    python benchmarks/bench_odom.py                           # every scenario, 3 alternating runs each
    python benchmarks/bench_odom.py --scenarios walk car32 --repeats 5
    python benchmarks/bench_odom.py --scenarios --long         # only the 10-minute vs 1-minute comparison
"""

from __future__ import annotations

import argparse
import json
import os
import shutil
import statistics
import subprocess
import sys
import tempfile
import time
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from bytecode_cache import use_bytecode_cache

from lio_cli.evaluation import EvalOptions, evaluate
from lio_cli.model.trajectory import Trajectory
from lio_cli.geometry import inv_pose
from lio_cli.io.files.trajectory import format_tum, read_tum
from lio_cli.simulation.run import simulate

BIN = Path(sys.executable).parent
STAGES = ("read_decode", "propagate", "deskew", "register", "degeneracy", "fuse")


@dataclass(frozen=True)
class Scenario:
    world: str  # lio simulate's scenario
    duration_s: float
    options: dict = field(default_factory=dict)
    what: str = ""


SCENARIOS = {
    "walk": Scenario("handheld", 30.0, {}, "lio simulate handheld --duration 30: 16 beams, standing start"),
    "sweep": Scenario("handheld", 40.0, {"start": "moving", "imu_rotation_deg": (180.0, 0.0, 0.0)},
                      "hand-held 16-beam walk, fast yaw sweeps, IMU upside down, moving start"),
    "car32": Scenario("drive", 60.0, {"start": "moving"}, "car, 32 beams, 60 s, moving start at 7.5 m/s"),
    "car64": Scenario("drive", 30.0, {"start": "moving", "beams": 64}, "car, 64 beams, moving start"),
    "car128": Scenario("drive", 30.0, {"start": "moving", "beams": 128}, "car, 128 beams, moving start"),
    "drive": Scenario("drive", 30.0, {}, "lio simulate drive --duration 30: 32 beams, standing start"),
    "corridor": Scenario("corridor", 30.0, {}, "featureless corridor, wheels, standing start"),
    "planar": Scenario("planar", 30.0, {}, "2D LaserScan office robot (lio alone)"),
}
LONG = ("handheld", 60.0, 600.0)  # a 1-minute and a 10-minute walk: flat memory, linear cost


# forks the command from a small process: a child forked from this one would count this process's memory (the
# simulated log's arrays) in its peak RSS until it execs; prints the command's own peak RSS (kB) last on stderr
_LAUNCH = ("import os, sys\npid = os.fork()\nif pid == 0:\n    os.execvp(sys.argv[1], sys.argv[1:])\n"
           "_, status, usage = os.wait4(pid, 0)\nsys.stderr.write(f'\\nmaxrss_kb {usage.ru_maxrss}\\n')\n"
           "sys.exit(os.waitstatus_to_exitcode(status))")


def run(cmd: list[str], cwd: Path) -> tuple[float, float, int, float]:
    """(wall s, peak RSS MB, exit code, CPU s: user + system over all threads) of one command in its own process.

    Wall time follows the machine's load; CPU time much less so, which keeps ratios honest on a busy machine."""
    t0 = time.perf_counter()
    proc = subprocess.Popen([sys.executable, "-S", "-c", _LAUNCH, *cmd], cwd=cwd, stdout=subprocess.DEVNULL,
                            stderr=subprocess.PIPE)
    err = proc.stderr.read().decode(errors="replace")
    _, status, usage = os.wait4(proc.pid, 0)
    wall = time.perf_counter() - t0
    err, _, rss = err.rpartition("maxrss_kb ")
    code = os.waitstatus_to_exitcode(status)
    if code != 0:
        print(f"  ! {' '.join(cmd[:2])} exited {code}: {err.strip().splitlines()[-1] if err.strip() else ''}",
              file=sys.stderr)
    peak_mb = int(rss) / 1024.0 if rss.strip().isdigit() else usage.ru_maxrss / 1024.0
    return wall, peak_mb, code, usage.ru_utime + usage.ru_stime


def ensure_rko(venv: Path) -> Path | None:
    exe = venv / "bin" / "rko_lio"
    if not exe.exists():
        print(f"installing rko-lio into {venv} ...", file=sys.stderr)
        subprocess.run([sys.executable, "-m", "venv", str(venv)], check=True)
        r = subprocess.run([str(venv / "bin" / "pip"), "install", "-q", "rko-lio", "rosbags"])
        if r.returncode != 0:
            return None
    return exe if exe.exists() else None


def metrics(gt: Path, est: Path) -> tuple[float, float | None]:
    ref = Trajectory(*read_tum(gt), name="gt")
    e = Trajectory(*read_tum(est), name=est.name)
    ate = evaluate(ref, e, EvalOptions(max_diff_ns=20_000_000)).stats["ape"]["trans"]["rmse"]
    try:
        rpe = evaluate(ref, e, EvalOptions(max_diff_ns=20_000_000, delta=10.0, delta_unit="m")).stats["rpe"]["trans"]["rmse"]
    except Exception:  # noqa: BLE001 - trajectory shorter than 10 m
        rpe = None
    return ate, rpe


def lidar_to_base(tum: Path, T_base_lidar: np.ndarray, out: Path) -> Path:
    stamps, P = read_tum(tum)
    out.write_text(format_tum(stamps, T_base_lidar @ P @ inv_pose(T_base_lidar)))
    return out


def median_run(runs: list[tuple[float, float, int, float]]) -> tuple[float, float, int, float]:
    """The run of median CPU time (its wall time and memory with it), or a failed run if any failed."""
    failed = [r for r in runs if r[2] != 0]
    if failed:
        return failed[0]
    return sorted(runs, key=lambda r: r[3])[len(runs) // 2]


def lio_cmd(log: Path, out: Path) -> list[str]:
    return [str(BIN / "lio"), "odom", str(log), "-o", str(out), "-q", "--force"]


def stage_ms(metrics_json: Path) -> dict:
    """ms per used scan of each stage, the median registration, the real-time factor, from lio's metrics.json."""
    m = json.loads(metrics_json.read_text())
    used = max(1, m["scans"]["used"])
    out = {k: 1000.0 * m["time_s"].get(k, 0.0) / used for k in STAGES}
    out["register_median"] = m.get("time_per_scan_ms", {}).get("register_median")
    out["scans"] = used
    return out


def scenario_rows(name: str, sc: Scenario, work: Path, args, rko: Path | None) -> list[dict]:
    d = work / name
    shutil.rmtree(d, ignore_errors=True)
    (d / "bag").mkdir(parents=True)
    duration = args.duration or sc.duration_s
    t0 = time.perf_counter()
    res = simulate(sc.world, d / "bag" / f"{name}.bag", "ros1", duration_s=duration, seed=args.seed, force=True,
                   **sc.options)
    print(f"{name}: simulated {duration:.0f} s in {time.perf_counter() - t0:.1f} s", file=sys.stderr)
    T_bl = np.asarray(json.loads(res.truth_path.read_text())["T_base_lidar"])
    lidar = "/points" if "/points" in res.topics else "/scan"
    rows = []

    def add(tool: str, est: Path | None, wall: float, mem: float, code: int, cpu: float, **extra) -> None:
        ate, rpe = metrics(res.gt_path, est) if code == 0 and est and est.exists() else (None, None)
        rows.append({"scenario": name, "tool": tool, "ate_m": ate, "rpe10m_m": rpe, "wall_s": wall, "peak_mb": mem,
                     "cpu_s": cpu, "log_s": duration, **extra})

    lio_out = d / "lio.tum"
    rko_cmd = None if rko is None or lidar != "/points" else [
        str(rko), str(d / "bag"), "--imu", "/imu", "--lidar", lidar, "--base_frame", "base", "-o", str(d / "rko")]
    lio_runs, rko_runs = [], []
    for _ in range(args.repeats):  # alternating, so that both see the same load
        lio_runs.append(run(lio_cmd(res.log_path, lio_out), d))
        if rko_cmd is not None:
            shutil.rmtree(d / "rko", ignore_errors=True)
            rko_runs.append(run(rko_cmd, d))
    lio_run = median_run(lio_runs)
    stages = stage_ms(d / "lio.odom.metrics.json") if lio_run[2] == 0 else {}
    add("lio", lio_out, *lio_run, stages=stages)
    if rko_runs:
        found = sorted((d / "rko").glob("*/*_tum.txt"))
        add("rko-lio", found[-1] if found else None, *median_run(rko_runs))
    if lidar == "/points" and not args.no_kiss:
        wall, mem, code, cpu = run([str(BIN / "kiss_icp_pipeline"), "--topic", lidar, str(res.log_path)], d)
        found = sorted((d / "results").glob("*/*_tum.txt"))
        est = lidar_to_base(found[-1], T_bl, d / "kiss_base.tum") if code == 0 and found else None
        add("kiss-icp", est, wall, mem, code, cpu)
    return rows


def long_rows(work: Path, args) -> list[dict]:
    """lio on a 1-minute and a 10-minute walk: peak RSS and CPU per scan of each."""
    world, short_s, long_s = LONG
    rows = []
    for duration in (short_s, long_s):
        d = work / f"long-{duration:.0f}s"
        shutil.rmtree(d, ignore_errors=True)
        d.mkdir(parents=True)
        t0 = time.perf_counter()
        res = simulate(world, d / f"walk-{duration:.0f}s.bag", "ros1", duration_s=duration, seed=args.seed,
                       force=True, start="moving")
        print(f"long: simulated {duration:.0f} s in {time.perf_counter() - t0:.1f} s", file=sys.stderr)
        wall, mem, code, cpu = run(lio_cmd(res.log_path, d / "lio.tum"), d)
        scans = stage_ms(d / "lio.odom.metrics.json")["scans"] if code == 0 else None
        ate = metrics(res.gt_path, d / "lio.tum")[0] if code == 0 else None
        rows.append({"log_s": duration, "wall_s": wall, "cpu_s": cpu, "peak_mb": mem, "scans": scans, "ate_m": ate})
        res.log_path.unlink()  # a 10-minute log is gigabytes
    return rows


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--scenarios", nargs="*", default=list(SCENARIOS), choices=list(SCENARIOS))
    ap.add_argument("--duration", type=float, default=None, help="seconds of every scenario (default: its own)")
    ap.add_argument("--repeats", type=int, default=3, help="alternating runs of lio and RKO-LIO per scenario")
    ap.add_argument("--long", action="store_true", help="also compare a 10-minute log with a 1-minute one")
    ap.add_argument("--no-kiss", action="store_true", help="skip kiss-icp's pipeline")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--rko", type=Path, default=Path(tempfile.gettempdir()) / "lio-bench-rko-venv")
    ap.add_argument("--keep", type=Path, default=None, help="keep logs and trajectories in this folder")
    ap.add_argument("--json", type=Path, default=None, help="also write the rows as JSON")
    args = ap.parse_args()
    use_bytecode_cache()

    work = args.keep or Path(tempfile.mkdtemp(prefix="lio-bench-odom-"))
    work.mkdir(parents=True, exist_ok=True)
    rko = ensure_rko(args.rko) if args.scenarios else None
    rows = []
    for name in args.scenarios:
        rows += scenario_rows(name, SCENARIOS[name], work, args, rko)
        print_table(rows, file=sys.stderr)  # so far, in case a later scenario fails
    long = long_rows(work, args) if args.long else []
    print(f"{time.strftime('%Y-%m-%d')}, {os.cpu_count()} CPUs, load average {os.getloadavg()[0]:.1f}; "
          f"lio and RKO-LIO alternating, median of {args.repeats} runs; CPU = user + system of the whole process\n")
    print_table(rows)
    print()
    print_stages(rows)
    if long:
        print()
        print_long(long)
    if args.json:
        args.json.write_text(json.dumps({"rows": rows, "long": long}, indent=2))
    return 0


def _f(v, fmt: str) -> str:
    return "-" if v is None else format(v, fmt)


def print_table(rows: list[dict], file=None) -> None:
    print("| scenario | tool | ATE m | RPE 10 m (m) | wall s | CPU s | x real time (CPU) | peak MB | ATE / RKO-LIO "
          "| CPU / RKO-LIO | wall / RKO-LIO |", file=file)
    print("|---|---|---|---|---|---|---|---|---|---|---|", file=file)
    for r in rows:
        rko = next((p for p in rows if p["scenario"] == r["scenario"] and p["tool"] == "rko-lio"), None)

        def ratio(key):
            if rko is None or r is rko or r[key] is None or rko[key] in (None, 0):
                return "-"
            return f"{r[key] / rko[key]:.2f}"

        print(f"| {r['scenario']} | {r['tool']} | {_f(r['ate_m'], '.3f')} | {_f(r['rpe10m_m'], '.3f')} | "
              f"{r['wall_s']:.1f} | {r['cpu_s']:.1f} | {r['log_s'] / r['cpu_s']:.1f} | {r['peak_mb']:.0f} | "
              f"{ratio('ate_m')} | {ratio('cpu_s')} | {ratio('wall_s')} |", file=file)


def print_stages(rows: list[dict]) -> None:
    print("| scenario | lio ms per scan: read+decode | propagate | deskew | register (median) | degeneracy | fuse "
          "| CPU per scan |")
    print("|---|---|---|---|---|---|---|---|")
    for r in rows:
        s = r.get("stages")
        if not s:
            continue
        print(f"| {r['scenario']} | {s['read_decode']:.2f} | {s['propagate']:.2f} | {s['deskew']:.2f} | "
              f"{s['register']:.2f} ({_f(s['register_median'], '.2f')}) | {s['degeneracy']:.2f} | {s['fuse']:.2f} | "
              f"{1000.0 * r['cpu_s'] / s['scans']:.1f} |")


def print_long(rows: list[dict]) -> None:
    print("| log | scans | lio peak MB | CPU s | CPU ms per scan | x real time (CPU) | ATE m |")
    print("|---|---|---|---|---|---|---|")
    for r in rows:
        per = _f(1000.0 * r["cpu_s"] / r["scans"] if r["scans"] else None, ".1f")
        print(f"| {r['log_s'] / 60:.0f} min walk | {_f(r['scans'], 'd')} | {r['peak_mb']:.0f} | {r['cpu_s']:.1f} | "
              f"{per} | {r['log_s'] / r['cpu_s']:.1f} | {_f(r['ate_m'], '.3f')} |")


if __name__ == "__main__":
    sys.exit(main())
