#!/usr/bin/env python3
"""`lio odom` on logs it was never tuned for: a matrix of start state, IMU mounting and IMU clock offset.

For every scenario x {still, moving start} x {IMU aligned, IMU rotated 180 deg roll + 90 deg yaw} x {IMU clock
offset 0, -15 ms (added to IMU stamps: the IMU clock runs 15 ms ahead)}, `lio simulate` writes one ROS 1 bag (seed
fixed, so every tool sees the same bytes) and four pipelines run on it, each in its own process: lio with default
options, lio LiDAR-only (`--prior constant-velocity --deskew constant-velocity`), kiss-icp's own pipeline and
RKO-LIO (extrinsics from /tf_static, `--base_frame base`; installed into a scratch venv as bench_odom.py does).
ATE = APE translation RMSE after SE(3) alignment against the exact ground truth, lio's evaluation code (evo's
definitions). The peers get no clock offset: nobody is told. planar (a 2D LaserScan, which neither peer reads) runs lio alone.

Targets (issue 8): in every cell lio default ATE <= 0.8x the better peer's and <= lio LiDAR-only's; lio's wall
time / RKO-LIO's no worse than bench_odom.py's 1.1-1.6.

    python benchmarks/robustness.py                          # 3D scenarios x 8 conditions, 20 s logs
    python benchmarks/robustness.py --scenarios handheld --duration 30 --keep /tmp/rob
"""

from __future__ import annotations

import argparse
import itertools
import json
import shutil
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from bytecode_cache import use_bytecode_cache

sys.path.insert(0, str(Path(__file__).resolve().parent))

from bench_odom import BIN, ensure_rko, lidar_to_base, metrics, run  # noqa: E402

from lio_cli.simulation.run import simulate  # noqa: E402

SCENARIOS = ("handheld", "drive", "corridor", "planar")
STARTS = ("still", "moving")
MOUNTS = {"aligned": (0.0, 0.0, 0.0), "rotated": (180.0, 0.0, 90.0)}
OFFSETS_S = (0.0, -0.015)  # added to IMU stamps to put them on the LiDAR's clock
LIO_ONLY = ["--prior", "constant-velocity", "--deskew", "constant-velocity"]


def cell(work: Path, scenario: str, start: str, mount: str, offset_s: float, duration: float, seed: int,
         rko: Path | None) -> dict:
    name = f"{scenario}-{start}-{mount}-{int(round(offset_s * 1000))}ms"
    d = work / name
    shutil.rmtree(d, ignore_errors=True)
    (d / "bag").mkdir(parents=True)
    res = simulate(scenario, d / "bag" / f"{name}.bag", "ros1", duration_s=duration, seed=seed, force=True,
                   start=start, imu_rotation_deg=MOUNTS[mount], imu_time_offset_s=offset_s)
    T_bl = np.asarray(json.loads(res.truth_path.read_text())["T_base_lidar"])
    lidar = "/points" if "/points" in res.topics else "/scan"
    row = {"scenario": scenario, "start": start, "imu": mount, "offset_ms": offset_s * 1000, "log_s": duration}

    def ate(est: Path | None, code: int) -> float | None:
        return metrics(res.gt_path, est)[0] if code == 0 and est is not None and est.exists() else None

    for tool, extra in (("lio", []), ("lio_lidar_only", LIO_ONLY)):
        out = d / f"{tool}.tum"
        wall, _, code, cpu = run([str(BIN / "lio"), "odom", str(res.log_path), "-o", str(out), "-q", "--force", *extra], d)
        row[tool], row[f"{tool}_wall_s"], row[f"{tool}_cpu_s"] = ate(out, code), wall, cpu
    if lidar == "/points":
        wall, _, code, cpu = run([str(BIN / "kiss_icp_pipeline"), "--topic", lidar, str(res.log_path)], d)
        found = sorted((d / "results").glob("*/*_tum.txt"))
        row["kiss_icp"] = ate(lidar_to_base(found[-1], T_bl, d / "kiss_base.tum") if found else None, code)
        if rko is not None:
            wall, _, code, cpu = run([str(rko), str(d / "bag"), "--imu", "/imu", "--lidar", lidar, "--base_frame", "base",
                                      "-o", str(d / "rko")], d)
            found = sorted((d / "rko").glob("*/*_tum.txt"))
            row["rko_lio"], row["rko_lio_wall_s"], row["rko_lio_cpu_s"] = ate(found[-1] if found else None, code), wall, cpu
    return row


def _f(v, fmt: str = ".3f") -> str:
    return "-" if v is None else format(v, fmt)


def verdict(r: dict) -> tuple[str, str]:
    """(lio / better peer, pass|FAIL) for the cell's targets."""
    peers = [r.get(k) for k in ("kiss_icp", "rko_lio") if r.get(k) is not None]
    lio, lo = r.get("lio"), r.get("lio_lidar_only")
    if lio is None:
        return "-", "FAIL"
    ratio = lio / min(peers) if peers else None
    ok = (ratio is None or ratio <= 0.8) and (lo is None or lio <= lo)
    return _f(ratio, ".2f"), "pass" if ok else "FAIL"


def print_table(rows: list[dict]) -> None:
    print("| scenario | start | IMU | offset ms | lio ATE m | lio LiDAR-only | kiss-icp | RKO-LIO | lio / better peer "
          "| lio wall / RKO-LIO | lio CPU / RKO-LIO | target |")
    print("|---|---|---|---|---|---|---|---|---|---|---|---|")
    for r in rows:
        ratio, ok = verdict(r)
        wall = (_f(r["lio_wall_s"] / r["rko_lio_wall_s"], ".2f") if r.get("rko_lio_wall_s") else "-")
        cpu = (_f(r["lio_cpu_s"] / r["rko_lio_cpu_s"], ".2f") if r.get("rko_lio_cpu_s") else "-")
        print(f"| {r['scenario']} | {r['start']} | {r['imu']} | {r['offset_ms']:.0f} | {_f(r.get('lio'))} | "
              f"{_f(r.get('lio_lidar_only'))} | {_f(r.get('kiss_icp'))} | {_f(r.get('rko_lio'))} | {ratio} | {wall} | "
              f"{cpu} | {ok} |")
    passed = sum(verdict(r)[1] == "pass" for r in rows)
    walls = [r["lio_wall_s"] / r["rko_lio_wall_s"] for r in rows if r.get("rko_lio_wall_s")]
    cpus = [r["lio_cpu_s"] / r["rko_lio_cpu_s"] for r in rows if r.get("rko_lio_cpu_s")]
    print(f"\n{passed}/{len(rows)} cells meet both targets"
          + (f"; lio / RKO-LIO wall time: median {np.median(walls):.2f} ({min(walls):.2f}-{max(walls):.2f}), CPU time: "
             f"median {np.median(cpus):.2f} ({min(cpus):.2f}-{max(cpus):.2f})" if walls else ""))


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--duration", type=float, default=20.0)
    ap.add_argument("--scenarios", nargs="+", default=list(SCENARIOS), choices=SCENARIOS)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--rko", type=Path, default=Path(tempfile.gettempdir()) / "lio-bench-rko-venv")
    ap.add_argument("--keep", type=Path, default=None, help="keep logs and trajectories in this folder")
    ap.add_argument("--json", type=Path, default=None, help="also write the rows as JSON")
    args = ap.parse_args()
    use_bytecode_cache()
    work = args.keep or Path(tempfile.mkdtemp(prefix="lio-robustness-"))
    work.mkdir(parents=True, exist_ok=True)
    rko = ensure_rko(args.rko)
    rows = []
    for sc, start, mount, off in itertools.product(args.scenarios, STARTS, MOUNTS, OFFSETS_S):
        t0 = time.perf_counter()
        rows.append(cell(work, sc, start, mount, off, args.duration, args.seed, rko))
        r = rows[-1]
        print(f"{sc} {start} {mount} {off * 1000:.0f} ms: lio {_f(r.get('lio'))} lidar-only {_f(r.get('lio_lidar_only'))} "
              f"kiss {_f(r.get('kiss_icp'))} rko {_f(r.get('rko_lio'))} ({time.perf_counter() - t0:.0f} s)",
              file=sys.stderr)
    print_table(rows)
    if args.json:
        args.json.write_text(json.dumps(rows, indent=2))
    return 0


if __name__ == "__main__":
    sys.exit(main())
