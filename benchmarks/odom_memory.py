#!/usr/bin/env python3
"""`lio odom` in this process with its memory sampled every N scans: what grows over a long log.

Per sample: RSS, glibc's main heap (``mallinfo2``: its size, what is in use, what is free inside it) and the voxel
map's points; with ``--tracemalloc`` also the memory Python and numpy hold (its bookkeeping adds to the RSS). Memory
in use that stays flat while the heap grows is fragmentation, not something lio keeps.

    python benchmarks/odom_memory.py walk-180s.bag                  # every 300 scans
    python benchmarks/odom_memory.py walk-180s.bag --every 100 --tracemalloc
    python benchmarks/odom_memory.py walk-600s.bag --every 500 --out o.tum   # keep the trajectory (its md5)

The last line printed is the scans and the process's peak RSS (``ru_maxrss``) once the run has written its outputs.
"""

from __future__ import annotations

import argparse
import ctypes
import os
import resource
import runpy
import sys
import tempfile
import tracemalloc
from pathlib import Path

from lio_cli.core.odometry import loop


class _MallInfo2(ctypes.Structure):
    _fields_ = [(n, ctypes.c_size_t) for n in ("arena", "ordblks", "smblks", "hblks", "hblkhd", "usmblks", "fsmblks",
                                                "uordblks", "fordblks", "keepcost")]


def _heap() -> str:
    try:
        libc = ctypes.CDLL("libc.so.6")
        libc.mallinfo2.restype = _MallInfo2
    except (OSError, AttributeError):  # not glibc (or older than 2.33)
        return ""
    m = libc.mallinfo2()
    return (f" | {m.arena / 2**20:.1f} | {m.uordblks / 2**20:.1f} | {m.fordblks / 2**20:.1f} | "
            f"{m.hblkhd / 2**20:.1f}")


def _rss_mb() -> float:
    with open("/proc/self/statm") as f:
        return int(f.read().split()[1]) * os.sysconf("SC_PAGE_SIZE") / 2**20


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("log", type=Path)
    ap.add_argument("--every", type=int, default=300, help="scans between samples")
    ap.add_argument("--tracemalloc", action="store_true", help="also what Python and numpy hold")
    ap.add_argument("--out", type=Path, default=None, help="the trajectory (default: a temporary folder)")
    args, odom_args = ap.parse_known_args()
    print("| scan | RSS MB | heap MB | in use MB | free in the heap MB | mmapped MB | map points | traced MB |")
    print("|---|---|---|---|---|---|---|---|")
    process = loop.LioOdometry.process
    count = [0]

    def sampled(self, cloud):
        result = process(self, cloud)
        count[0] += 1
        if count[0] % args.every == 0:
            reg = self.run.reg
            points = len(reg.map.point_cloud()) if reg is not None else 0
            traced = f"{tracemalloc.get_traced_memory()[0] / 2**20:.1f}" if args.tracemalloc else "-"
            print(f"| {count[0]} | {_rss_mb():.1f}{_heap()} | {points} | {traced} |", flush=True)
        return result

    loop.LioOdometry.process = sampled
    if args.tracemalloc:
        tracemalloc.start()
    out = args.out or Path(tempfile.mkdtemp(prefix="lio-odom-memory-")) / "odom.tum"
    sys.argv = ["lio", "odom", str(args.log), "-o", str(out), "-q", "--force", *odom_args]
    try:
        runpy.run_module("lio_cli", run_name="__main__")
    except SystemExit as done:
        code = int(done.code or 0)
    else:
        code = 0
    print(f"scans {count[0]}, peak RSS {resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024:.1f} MB")
    return code


if __name__ == "__main__":
    sys.exit(main())
