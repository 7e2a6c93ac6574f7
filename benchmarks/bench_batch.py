#!/usr/bin/env python3
"""`lio batch`: throughput of local processes and of a local Dask cluster against serial runs, and the Dask
path's overhead per task.

Simulates N handheld logs (default 8 x 20 s, ROS 1 bags, seeds 0..N-1) and runs `lio batch odom LOGS --gt
/ground_truth` over them, each mode in a fresh `lio` process as a user would: `--jobs 1` (serial: one run after
another in one process), `--jobs W` (local processes), `--dask local --workers W`. Prints wall time, logs per
minute and the ratio to serial (target >= 1.7x with W = 2 on 2 cores), and the overhead per task of each
parallel mode: wall x workers / N - the mean run time the summary reports (scheduling, process start-up,
transfer: target <= 0.5 s for Dask), with and without the Dask cluster's start-up (timed on its own).
Every mode's trajectories are checked to be byte-identical to the serial ones. The load average before and
after is printed: other work on the machine lowers every ratio.

    python benchmarks/bench_batch.py
    python benchmarks/bench_batch.py --logs 4 --duration 10 --workers 2
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

from bytecode_cache import use_bytecode_cache
from lio_cli.simulation.run import simulate

LIO = [sys.executable, "-c", "import sys; from lio_cli.cli.app import entry; sys.argv[0] = 'lio'; entry()"]


def batch(logs: list[Path], out: Path, extra: list[str]) -> tuple[float, dict]:
    t0 = time.perf_counter()
    proc = subprocess.run([*LIO, "batch", "odom", *map(str, logs), "--gt", "/ground_truth", "-O", str(out), "-q",
                           *extra], stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True)
    wall = time.perf_counter() - t0
    if proc.returncode != 0:
        sys.exit(f"lio batch {' '.join(extra)} failed ({proc.returncode}): {proc.stderr}")
    return wall, json.loads((out / "summary.json").read_text())


def dask_startup(workers: int) -> float:
    """Seconds to start (and stop) the local Dask cluster --dask local builds, alone."""
    code = ("import logging, time; from distributed import Client, LocalCluster; t = time.perf_counter(); "
            f"c = LocalCluster(n_workers={workers}, threads_per_worker=1, processes=True, dashboard_address=None, "
            "silence_logs=logging.ERROR); cl = Client(c); cl.close(); c.close(); print(time.perf_counter() - t)")
    return float(subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True).stdout)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--logs", type=int, default=8)
    ap.add_argument("--duration", type=float, default=20.0)
    ap.add_argument("--workers", type=int, default=2)
    ap.add_argument("--keep", type=Path, help="work in this folder and keep it (default: a temporary one)")
    args = ap.parse_args()
    use_bytecode_cache()
    root = args.keep or Path(tempfile.mkdtemp(prefix="lio-bench-batch-"))
    root.mkdir(parents=True, exist_ok=True)
    (root / "logs").mkdir(exist_ok=True)
    t0 = time.perf_counter()
    logs = [simulate("handheld", root / "logs" / f"walk{i}.bag", duration_s=args.duration, seed=i,
                     force=True).log_path for i in range(args.logs)]
    print(f"simulated {args.logs} handheld logs of {args.duration:g} s in {time.perf_counter() - t0:.0f} s")
    load0 = os.getloadavg()
    w = args.workers
    modes = {"serial (--jobs 1)": ["--jobs", "1"], f"--jobs {w}": ["--jobs", str(w)],
             f"--dask local --workers {w}": ["--dask", "local", "--workers", str(w)]}
    results = {}
    for i, (name, extra) in enumerate(modes.items()):
        out = root / f"out{i}"
        shutil.rmtree(out, ignore_errors=True)
        results[name] = (*batch(logs, out, extra), out)
    startup = dask_startup(w)
    load1 = os.getloadavg()

    serial_wall, _, serial_out = results["serial (--jobs 1)"]
    n = args.logs
    print(f"\nload average before {load0[0]:.2f}, after {load1[0]:.2f} (2 cores: above 2 means other work shares "
          "them); Dask cluster start-up alone: {:.2f} s\n".format(startup))
    print(f"{'mode':<28}{'wall s':>8}{'logs/min':>10}{'x serial':>10}{'mean run s':>12}{'overhead/task s':>17}"
          f"{'excl. start-up':>16}  identical")
    for name, (wall, summary, out) in results.items():
        runs = summary["runs"]
        mean_run = sum(r["time_s"] for r in runs) / n
        workers = 1 if name.startswith("serial") else w
        overhead = wall * workers / n - mean_run
        excl = (wall - startup) * workers / n - mean_run if "dask" in name else None
        same = all((out / r["name"] / "odom.tum").read_bytes() == (serial_out / r["name"] / "odom.tum").read_bytes()
                   for r in runs)
        print(f"{name:<28}{wall:>8.1f}{60 * n / wall:>10.1f}{serial_wall / wall:>10.2f}{mean_run:>12.2f}"
              f"{overhead:>17.2f}{'-' if excl is None else f'{excl:.2f}':>16}  {'yes' if same else 'NO'}")
    print("\ntargets: --jobs 2 and --dask local --workers 2 each >= 1.7x serial; Dask overhead per task <= 0.5 s")
    if args.keep is None:
        shutil.rmtree(root, ignore_errors=True)


if __name__ == "__main__":
    main()
