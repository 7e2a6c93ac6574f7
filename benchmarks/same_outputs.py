#!/usr/bin/env python3
"""Same outputs before and after a refactor: lio from two source trees over the same logs, compared file by file.

    python benchmarks/same_outputs.py gen LOGS                  # the logs: bench_odom's 4 scenarios (30 s) and
                                                                #   robustness.py's 32 cells (20 s), seed 0
    python benchmarks/same_outputs.py run TREE LOGS OUT         # lio from TREE (a checkout, e.g. a worktree of the
                                                                #   old commit) on the sample logs and LOGS
    python benchmarks/same_outputs.py cmp OUT_A OUT_B           # TUM files byte for byte, else the largest |diff|

`run` writes per log: odom (default; LiDAR-only too on the robustness cells), and on the sample logs fuse with and
without `--odom`, calibrate and deskew of the walk, then odom on the de-skewed walk. kiss-icp's threaded sums may
move the last bit of a pose from run to run (|diff| ~1e-9 m), so a difference that small is not a change.
"""

from __future__ import annotations

import itertools
import os
import subprocess
import sys
from pathlib import Path

import numpy as np

SCENARIOS = ("handheld", "drive", "corridor", "planar")
MOUNTS = {"aligned": (0.0, 0.0, 0.0), "rotated": (180.0, 0.0, 90.0)}
LIDAR_ONLY = ["--prior", "constant-velocity", "--deskew", "constant-velocity"]


def gen(logs: Path) -> None:
    from lio_cli.simulation.run import simulate

    cells = [(f"bench-{sc}", sc, {"duration_s": 30.0}) for sc in SCENARIOS]
    for sc, start, mount, late_ms in itertools.product(SCENARIOS, ("still", "moving"), MOUNTS, (0, 15)):
        cells.append((f"rob-{sc}-{start}-{mount}-{late_ms}", sc, {
            "duration_s": 20.0, "start": start, "imu_rotation_deg": MOUNTS[mount],
            "imu_time_offset_s": -late_ms / 1000}))  # the IMU clock late_ms behind
    for name, scenario, kw in cells:
        out = logs / name / f"{name}.bag"
        if not out.exists():
            out.parent.mkdir(parents=True, exist_ok=True)
            simulate(scenario, out, "ros1", seed=0, force=True, **kw)
            print("made", name, flush=True)


def _lio(tree: Path, args: list[str], cwd: Path) -> None:
    env = {**os.environ, "PYTHONPATH": str(tree)}
    r = subprocess.run([sys.executable, "-m", "lio_cli", *map(str, args), "-q", "--force"], cwd=cwd, env=env,
                       capture_output=True, text=True)
    if r.returncode:
        print(f"{cwd.name}: lio {args[0]} exited {r.returncode}: {r.stderr.strip().splitlines()[-1:]}", flush=True)


def run(tree: Path, logs: Path, out: Path) -> None:
    sample = tree / "sample_logs"
    jobs = [("sample-handheld", sample / "handheld.bag"), ("sample-corridor", sample / "corridor_ros2"),
            ("sample-planar", sample / "planar.mcap")]
    jobs += [(d.name, d / f"{d.name}.bag") for d in sorted(logs.iterdir()) if d.is_dir()]
    for name, log in jobs:
        d = out / name
        d.mkdir(parents=True, exist_ok=True)
        _lio(tree, ["odom", log, "-o", d / "odom.tum"], d)
        if name.startswith("rob-"):
            _lio(tree, ["odom", log, "-o", d / "lidar-only.tum", *LIDAR_ONLY], d)
        if name.startswith("sample-"):
            _lio(tree, ["fuse", log, "-o", d / "fuse.tum"], d)
            _lio(tree, ["fuse", log, "--odom", d / "odom.tum", "-o", d / "fuse-odom.tum"], d)
    d = out / "sample-handheld"
    _lio(tree, ["calibrate", sample / "handheld.bag", "-o", d / "calib.yaml"], d)
    _lio(tree, ["deskew", sample / "handheld.bag", d / "deskewed.bag"], d)
    _lio(tree, ["odom", d / "deskewed.bag", "--deskew", "none", "-o", d / "odom-deskewed.tum"], d)


def _numbers(path: Path) -> np.ndarray:
    return np.array([[float(x) for x in line.split()] for line in path.read_text().splitlines()
                     if line and not line.startswith("#")])


def cmp(a: Path, b: Path) -> int:
    same, differ, worst = 0, 0, 0.0
    for f in sorted(a.rglob("*.tum")):
        g = b / f.relative_to(a)
        if g.exists() and f.read_bytes() == g.read_bytes():
            same += 1
            continue
        differ += 1
        if not g.exists() or _numbers(f).shape != _numbers(g).shape:
            print(f"{f.relative_to(a)}: missing or a different number of poses")
            continue
        d = float(np.abs(_numbers(f) - _numbers(g)).max())
        worst = max(worst, d)
        print(f"{f.relative_to(a)}: max |diff| {d:.3g}")
    for name in ("calib.yaml", "deskewed.bag"):
        for f in sorted(a.rglob(name)):
            g = b / f.relative_to(a)
            if name.endswith(".yaml"):  # values only: header comments may change
                strip = lambda p: [x for x in p.read_text().splitlines() if not x.startswith("#")]  # noqa: E731
                print(f"{f.relative_to(a)}: values", "same" if g.exists() and strip(f) == strip(g) else "DIFFER")
            else:
                print(f"{f.relative_to(a)}:", "same bytes" if g.exists() and f.read_bytes() == g.read_bytes() else "DIFFER")
    print(f"{same} TUM files identical, {differ} differ (max |diff| {worst:.3g})")
    return 0


def main() -> int:
    if len(sys.argv) < 3 or sys.argv[1] not in ("gen", "run", "cmp"):
        print(__doc__, file=sys.stderr)
        return 2
    what, args = sys.argv[1], [Path(p).resolve() for p in sys.argv[2:]]
    if what == "gen":
        gen(*args)
    elif what == "run":
        run(*args)
    else:
        cmp(*args)
    return 0


if __name__ == "__main__":
    sys.exit(main())
