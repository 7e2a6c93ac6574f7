#!/usr/bin/env python3
"""Accuracy and speed of `lio odom` against kiss-icp (LiDAR-only) and RKO-LIO (LiDAR-inertial).

Simulates each scenario once with `lio simulate` (ROS 1 bag, the format all three tools read), runs the
three pipelines on the same log, each in its own process (wall time and peak RSS of that process), and
evaluates every trajectory of the base frame against the exact ground truth with lio's evaluation code
(evo's APE/RPE definitions): ATE = APE translation RMSE after SE(3) alignment, RPE = translation RMSE over
10 m segments. kiss-icp's poses (LiDAR frame) are moved to the base frame with the true extrinsic.

RKO-LIO is installed into a scratch venv (`pip install rko-lio rosbags`) unless --rko points at one.
Neither peer reads a 2D LaserScan, so `planar` runs lio alone.

    python benchmarks/bench_odom.py                      # 4 scenarios x 30 s
    python benchmarks/bench_odom.py --duration 60 --scenarios handheld drive
"""

from __future__ import annotations

import argparse
import json
import os
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from bytecode_cache import use_bytecode_cache

from lio_cli.evaluation import EvalOptions, evaluate
from lio_cli.model.trajectory import Trajectory
from lio_cli.geometry import inv_pose
from lio_cli.io.files.trajectory import format_tum, read_tum
from lio_cli.simulation.run import simulate

SCENARIOS = ("handheld", "drive", "corridor", "planar")
BIN = Path(sys.executable).parent


def run(cmd: list[str], cwd: Path) -> tuple[float, float, int, float]:
    """(wall s, peak RSS MB, exit code, CPU s: user + system over all threads) of one command in its own process.

    Wall time follows the machine's load; CPU time much less so, which keeps ratios honest on a busy machine."""
    t0 = time.perf_counter()
    proc = subprocess.Popen(cmd, cwd=cwd, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE)
    _, status, usage = os.wait4(proc.pid, 0)
    wall = time.perf_counter() - t0
    err = proc.stderr.read().decode(errors="replace") if proc.stderr else ""
    code = os.waitstatus_to_exitcode(status)
    if code != 0:
        print(f"  ! {' '.join(cmd[:2])} exited {code}: {err.strip().splitlines()[-1] if err.strip() else ''}",
              file=sys.stderr)
    return wall, usage.ru_maxrss / 1024.0, code, usage.ru_utime + usage.ru_stime


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


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--duration", type=float, default=30.0)
    ap.add_argument("--scenarios", nargs="+", default=list(SCENARIOS), choices=SCENARIOS)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--rko", type=Path, default=Path(tempfile.gettempdir()) / "lio-bench-rko-venv")
    ap.add_argument("--keep", type=Path, default=None, help="keep logs and trajectories in this folder")
    ap.add_argument("--json", type=Path, default=None, help="also write the rows as JSON")
    args = ap.parse_args()
    use_bytecode_cache()

    work = args.keep or Path(tempfile.mkdtemp(prefix="lio-bench-odom-"))
    work.mkdir(parents=True, exist_ok=True)
    rko = ensure_rko(args.rko)
    rows = []
    for sc in args.scenarios:
        d = work / sc
        shutil.rmtree(d, ignore_errors=True)
        (d / "bag").mkdir(parents=True)
        t0 = time.perf_counter()
        res = simulate(sc, d / "bag" / f"{sc}.bag", "ros1", duration_s=args.duration, seed=args.seed, force=True)
        print(f"{sc}: simulated {args.duration:.0f} s in {time.perf_counter() - t0:.1f} s", file=sys.stderr)
        truth = json.loads(res.truth_path.read_text())
        T_bl = np.asarray(truth["T_base_lidar"])
        topics = {t for t in res.topics}
        lidar = "/points" if "/points" in topics else "/scan"

        def add(tool: str, est: Path | None, wall: float, mem: float, code: int, cpu: float) -> None:
            ate, rpe = metrics(res.gt_path, est) if code == 0 and est and est.exists() else (None, None)
            rows.append({"scenario": sc, "tool": tool, "ate_m": ate, "rpe10m_m": rpe, "wall_s": wall, "peak_mb": mem,
                         "cpu_s": cpu, "log_s": args.duration})

        out = d / "lio.tum"
        add("lio", out, *run([str(BIN / "lio"), "odom", str(res.log_path), "-o", str(out), "-q", "--force"], d))
        if lidar == "/points":
            kd = d / "kiss"
            wall, mem, code, cpu = run([str(BIN / "kiss_icp_pipeline"), "--topic", lidar, str(res.log_path)], kd.parent)
            found = sorted((d / "results").glob("*/*_tum.txt"))
            est = lidar_to_base(found[-1], T_bl, d / "kiss_base.tum") if code == 0 and found else None
            add("kiss-icp", est, wall, mem, code, cpu)
            if rko is not None:
                wall, mem, code, cpu = run([str(rko), str(d / "bag"), "--imu", "/imu", "--lidar", lidar, "--base_frame",
                                            "base", "-o", str(d / "rko")], d)
                found = sorted((d / "rko").glob("*/*_tum.txt"))
                add("rko-lio", found[-1] if found else None, wall, mem, code, cpu)
    print_table(rows)
    if args.json:
        args.json.write_text(json.dumps(rows, indent=2))
    return 0


def _f(v, fmt: str) -> str:
    return "-" if v is None else format(v, fmt)


def print_table(rows: list[dict]) -> None:
    print("| scenario | tool | ATE m | RPE 10 m (m) | wall s | CPU s | x real time | peak MB | ATE / kiss-icp | ATE / RKO-LIO "
          "| wall / RKO-LIO | CPU / RKO-LIO |")
    print("|---|---|---|---|---|---|---|---|---|---|---|---|")
    for r in rows:
        peers = {p["tool"]: p for p in rows if p["scenario"] == r["scenario"]}
        kiss, rko = peers.get("kiss-icp"), peers.get("rko-lio")

        def ratio(key, peer):
            if peer is None or r[key] is None or peer[key] in (None, 0):
                return "-"
            return f"{r[key] / peer[key]:.2f}"

        print(f"| {r['scenario']} | {r['tool']} | {_f(r['ate_m'], '.3f')} | {_f(r['rpe10m_m'], '.3f')} | "
              f"{r['wall_s']:.1f} | {r['cpu_s']:.1f} | {r['log_s'] / r['wall_s']:.1f} | {r['peak_mb']:.0f} | "
              f"{ratio('ate_m', kiss)} | {ratio('ate_m', rko)} | {ratio('wall_s', rko)} | {ratio('cpu_s', rko)} |")


if __name__ == "__main__":
    sys.exit(main())
