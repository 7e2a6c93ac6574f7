"""Simulation benchmark: how fast `lio simulate` writes logs, per scenario and format.

The issue's goal: 60 s of the 16-beam handheld scenario (1024 columns, 200 Hz IMU) in under a minute on a
2-core machine. Each case runs in this process (the work is single-threaded numpy) into a temporary folder
and prints a table: seconds simulated, wall time, real-time factor (simulated / wall), MB written, and the
share of wall time spent ray casting (measured separately on the same scans).

  python benchmarks/bench_simulate.py                               # handheld 60 s, ros1
  python benchmarks/bench_simulate.py --scenarios handheld,drive,corridor,planar --formats ros1,mcap --duration 20
  python benchmarks/bench_simulate.py --beams 32 --columns 2048
"""

from __future__ import annotations

import argparse
import shutil
import tempfile
import time
from pathlib import Path

SUFFIX = {"ros1": ".bag", "ros2": "", "ros2-mcap": "", "mcap": ".mcap"}


def _size_mb(path: Path) -> float:
    files = [p for p in path.rglob("*") if p.is_file()] if path.is_dir() else [path]
    return sum(f.stat().st_size for f in files) / 1e6


def run_case(scenario: str, fmt: str, duration_s: float, beams: int | None, columns: int | None, root: Path) -> dict:
    from lio_cli.simulation import simulate

    out = root / f"{scenario}_{fmt.replace('-', '_')}{SUFFIX[fmt]}"
    t0 = time.perf_counter()
    res = simulate(scenario, out, fmt, duration_s=duration_s, seed=0, beams=beams, columns=columns)
    wall = time.perf_counter() - t0
    mb = _size_mb(out)
    scans = res.topics.get("/points", res.topics.get("/scan", {})).get("count", 0)
    return {"scenario": scenario, "format": fmt, "sim_s": duration_s, "wall_s": wall, "rtf": duration_s / wall,
            "mb": mb, "scans": scans}


def raycast_share(scenario: str, beams: int | None, columns: int | None, n_scans: int = 30) -> float:
    """Seconds per scan spent in ray casting alone (spin_scan without writing)."""
    import numpy as np

    from lio_cli.simulation import build_scenario
    from lio_cli.simulation.sensors import LidarSpec, laser_scan, spin_scan

    sc = build_scenario(scenario, beams, columns)
    rng = np.random.default_rng(0)
    t0 = time.perf_counter()
    for k in range(n_scans):
        start = 2_000_000_000 + k * sc.lidar.period_ns
        if isinstance(sc.lidar, LidarSpec):
            spin_scan(sc.world, sc.trajectory, sc.T_base_lidar, sc.lidar, start, 0, rng)
        else:
            laser_scan(sc.world, sc.trajectory, sc.T_base_lidar, sc.lidar, start, 0, rng)
    return (time.perf_counter() - t0) / n_scans


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--scenarios", default="handheld")
    ap.add_argument("--formats", default="ros1")
    ap.add_argument("--duration", type=float, default=60.0)
    ap.add_argument("--beams", type=int, default=None)
    ap.add_argument("--columns", type=int, default=None)
    args = ap.parse_args()
    root = Path(tempfile.mkdtemp(prefix="bench_simulate_"))
    rows = []
    try:
        for scenario in args.scenarios.split(","):
            per_scan = raycast_share(scenario, args.beams, args.columns)
            for fmt in args.formats.split(","):
                row = run_case(scenario, fmt, args.duration, args.beams, args.columns, root)
                row["scan_s"] = per_scan
                rows.append(row)
                print(f"  done {scenario} {fmt}: {row['wall_s']:.1f} s", flush=True)
    finally:
        shutil.rmtree(root, ignore_errors=True)
    head = f"{'scenario':<10} {'format':<9} {'sim s':>6} {'wall s':>7} {'x real':>7} {'MB':>8} {'scans':>6} {'sensor model ms/scan':>21}"
    print(head)
    print("-" * len(head))
    for r in rows:
        print(f"{r['scenario']:<10} {r['format']:<9} {r['sim_s']:>6.1f} {r['wall_s']:>7.1f} {r['rtf']:>7.2f} "
              f"{r['mb']:>8.1f} {r['scans']:>6d} {r['scan_s'] * 1e3:>21.1f}")


if __name__ == "__main__":
    main()
