"""Read benchmark: lio's decode of a log into one sensor stream, next to bare iteration of the raw messages.

Writes synthetic logs (32-beam LiDAR at 10 Hz with per-point time, IMU at 200 Hz, /tf_static) of a short and a
10x longer duration in each format, then measures, each case in a fresh subprocess (so peak RSS is its own):

  bare    iterate the raw serialised messages of the LiDAR and IMU topics, no deserialisation
          (rosbags AnyReader.messages for ROS 1/ROS 2 bags, the mcap reader for bare MCAP)
  deser   the same plus rosbags' typestore deserialisation of every message (for scale: what reading
          the log "the usual way" costs, before any numpy work)
  decode  lio's full path: open_log -> SensorStream (typed clouds with per-point ns stamps, IMU batches)
  info    open_log + describe_log, what `lio info` does (index, first scan, /tf_static)

and prints a table: scans/s and MB/s of decode, the decode/bare time ratio (goal <= 1.25) and peak memory of
each, for both durations, so bounded memory and info's independence from log length are visible.

  python benchmarks/bench_read.py                       # 30 s and 300 s, all formats
  python benchmarks/bench_read.py --durations 10,100 --formats ros1,mcap --repeat 3
"""

from __future__ import annotations

import argparse
import json
import os
import resource
import shutil
import subprocess
import sys
import tempfile
import time
from collections import deque
from pathlib import Path

import numpy as np

T0_NS = 1_700_000_000 * 10**9
LIDAR, IMU = "/points", "/imu"
SUFFIX = {"ros1": ".bag", "ros2": "", "ros2-mcap": "", "mcap": ".mcap"}


# ---- synthetic log -----------------------------------------------------------------------------------


def write_log(path: Path, fmt: str, duration_s: float, beams: int, columns: int, seed: int = 0) -> None:
    from lio_cli.geometry import make_pose
    from lio_cli.io.logs.writer import LogWriter

    rng = np.random.default_rng(seed)
    n = beams * columns
    dtype = np.dtype({"names": ["x", "y", "z", "intensity", "ring", "time"],
                      "formats": ["<f4", "<f4", "<f4", "<f4", "<u2", "<f4"],
                      "offsets": [0, 4, 8, 12, 16, 18], "itemsize": 22})
    az = np.tile(np.linspace(0.0, 2 * np.pi, columns, endpoint=False), beams)
    elev = np.repeat(np.radians(np.linspace(-15.0, 15.0, beams)), columns)
    base_r = 5.0 + 20.0 * rng.random(n)
    with LogWriter(path, fmt) as w:
        w.add_topic("/tf_static", "tf2_msgs/msg/TFMessage", latching=True)
        w.add_topic(LIDAR, "sensor_msgs/msg/PointCloud2")
        w.add_topic(IMU, "sensor_msgs/msg/Imu")
        w.write("/tf_static", T0_NS, w.make.tf_message([
            w.make.transform_stamped(T0_NS, "base_link", "imu_link", make_pose(t=[0.1, 0, 0.05])),
            w.make.transform_stamped(T0_NS, "imu_link", "velodyne", make_pose(t=[0, 0, 0.3]))]))
        imu_period, lidar_period = 5_000_000, 100_000_000
        end = T0_NS + int(duration_s * 1e9)
        next_scan = T0_NS
        for t in range(T0_NS, end, imu_period):
            w.write(IMU, t + 200_000, w.make.imu(t, "imu_link", rng.normal(0, 0.01, 3), [0.0, 0.0, 9.81]))
            if t >= next_scan + lidar_period:  # a scan is published when it is complete
                arr = np.zeros(n, dtype)
                r = base_r + rng.normal(0, 0.02, n)
                arr["x"], arr["y"], arr["z"] = r * np.cos(elev) * np.cos(az), r * np.cos(elev) * np.sin(az), r * np.sin(elev)
                arr["intensity"] = rng.random(n) * 100
                arr["ring"] = np.repeat(np.arange(beams), columns)
                arr["time"] = az / (2 * np.pi) * 0.1
                arr["x"][rng.random(n) < 0.05] = np.nan  # some no-returns
                w.write(LIDAR, t, w.make.pointcloud2(next_scan, "velodyne", arr, height=beams))
                next_scan += lidar_period


# ---- measurements (run in a subprocess each) --------------------------------------------------------


def _peak_rss_mb() -> float:
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0  # kB on Linux


def _import_all() -> None:
    """Import what either side needs before timing: imports are a constant, not reading cost."""
    import mcap.reader  # noqa: F401
    import rosbags.highlevel  # noqa: F401
    import rosbags.typesys  # noqa: F401

    import lio_cli.jobs.info  # noqa: F401
    import lio_cli.io.sensors.stream  # noqa: F401


# Consumers hold on to a few messages; a loop that drops each one at once makes glibc hand every large
# buffer back to the OS and fault it in again.
# Both sides keep the last few messages alive, as any real consumer (and lio's reorder heap) does.
KEEP = 16


def measure_bare(path: Path, fmt: str) -> dict:
    _import_all()
    nbytes = scans = msgs = 0
    keep: deque = deque(maxlen=KEEP)
    t0 = time.perf_counter()
    if fmt == "mcap":
        from mcap.reader import make_reader

        with path.open("rb") as f:
            for _, channel, message in make_reader(f).iter_messages(topics=[LIDAR, IMU], log_time_order=True):
                keep.append(message)
                nbytes += len(message.data)
                msgs += 1
                scans += channel.topic == LIDAR
    else:
        from rosbags.highlevel import AnyReader

        paths = [path]
        with AnyReader(paths) as reader:
            conns = [c for c in reader.connections if c.topic in (LIDAR, IMU)]
            for conn, _, raw in reader.messages(connections=conns):
                keep.append(raw)
                nbytes += len(raw)
                msgs += 1
                scans += conn.topic == LIDAR
    return {"seconds": time.perf_counter() - t0, "bytes": nbytes, "scans": scans, "messages": msgs,
            "peak_rss_mb": _peak_rss_mb()}


def measure_deser(path: Path, fmt: str) -> dict:
    """The usual rosbags way: iterate and deserialise every message into typestore objects (no numpy)."""
    _import_all()
    scans = 0
    keep: deque = deque(maxlen=KEEP)
    t0 = time.perf_counter()
    if fmt == "mcap":
        from mcap.reader import make_reader
        from rosbags.typesys import Stores, get_typestore

        ts = get_typestore(Stores.ROS2_HUMBLE)
        with path.open("rb") as f:
            for schema, channel, message in make_reader(f).iter_messages(topics=[LIDAR, IMU], log_time_order=True):
                keep.append(ts.deserialize_cdr(message.data, schema.name))
                scans += channel.topic == LIDAR
    else:
        from rosbags.highlevel import AnyReader

        with AnyReader([path]) as reader:
            conns = [c for c in reader.connections if c.topic in (LIDAR, IMU)]
            for conn, _, raw in reader.messages(connections=conns):
                keep.append(reader.deserialize(raw, conn.msgtype))
                scans += conn.topic == LIDAR
    return {"seconds": time.perf_counter() - t0, "scans": scans, "peak_rss_mb": _peak_rss_mb()}


def measure_decode(path: Path, fmt: str) -> dict:
    from lio_cli.io.logs.reader import open_log
    from lio_cli.io.sensors.stream import SensorStream

    _import_all()
    scans = imu = points = 0
    keep: deque = deque(maxlen=KEEP)
    t0 = time.perf_counter()
    with open_log(path) as log:
        for rec in SensorStream(log, {"lidar": LIDAR, "imu": IMU}):
            keep.append(rec)
            if rec.kind == "lidar":
                scans += 1
                points += len(rec.data.points)
            else:
                imu += len(rec.data)
    return {"seconds": time.perf_counter() - t0, "scans": scans, "imu_samples": imu, "points": points,
            "peak_rss_mb": _peak_rss_mb()}


def measure_info(path: Path, fmt: str, repeat: int = 3) -> dict:
    from lio_cli.jobs.info import describe_log
    from lio_cli.io.logs.reader import open_log

    _import_all()
    best = float("inf")
    for _ in range(repeat):
        t0 = time.perf_counter()
        with open_log(path) as log:
            describe_log(log)
        best = min(best, time.perf_counter() - t0)
    return {"seconds": best, "peak_rss_mb": _peak_rss_mb()}


MEASURES = {"bare": measure_bare, "deser": measure_deser, "decode": measure_decode, "info": measure_info}


def run_once(mode: str, path: Path, fmt: str) -> dict:
    out = subprocess.run([sys.executable, __file__, "--_measure", mode, str(path), fmt],
                         capture_output=True, text=True, check=True).stdout
    return json.loads(out.strip().splitlines()[-1])


def run_cases(modes: list[str], path: Path, fmt: str, repeat: int) -> dict[str, dict]:
    """Best of ``repeat`` fresh subprocesses per mode, the modes interleaved (bare, decode, bare, ...) so
    that a busy machine slows both sides alike; peak RSS is that of the best run."""
    best: dict[str, dict] = {}
    for _ in range(repeat):
        for mode in modes:
            res = run_once(mode, path, fmt)
            if mode not in best or res["seconds"] < best[mode]["seconds"]:
                best[mode] = res
    return best


def log_size_mb(path: Path) -> float:
    files = [path] if path.is_file() else [p for p in path.rglob("*") if p.is_file()]
    return sum(p.stat().st_size for p in files) / 1e6


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--durations", default="30,300", help="log durations in s, comma separated (default 30,300)")
    ap.add_argument("--formats", default="ros1,ros2,ros2-mcap,mcap")
    ap.add_argument("--beams", type=int, default=32)
    ap.add_argument("--columns", type=int, default=512, help="points per beam and scan (default 512)")
    ap.add_argument("--repeat", type=int, default=1, help="runs per measurement, best kept")
    ap.add_argument("--workdir", type=Path, help="keep logs here (reused if present) instead of a temp dir")
    ap.add_argument("--json", action="store_true", help="also print the rows as JSON")
    ap.add_argument("--_measure", nargs=3, help=argparse.SUPPRESS)
    args = ap.parse_args()

    if args._measure:
        mode, path, fmt = args._measure
        print(json.dumps(MEASURES[mode](Path(path), fmt)))
        return

    work = args.workdir or Path(tempfile.mkdtemp(prefix="lio-bench-"))
    work.mkdir(parents=True, exist_ok=True)
    durations = [float(d) for d in args.durations.split(",")]
    rows = []
    try:
        for fmt in args.formats.split(","):
            read_fmt = "ros2" if fmt == "ros2-mcap" else fmt
            for dur in durations:
                path = work / f"bench_{fmt}_{dur:g}s_{args.beams}x{args.columns}{SUFFIX[fmt]}"
                if not path.exists():
                    t0 = time.perf_counter()
                    write_log(path, fmt, dur, args.beams, args.columns)
                    print(f"wrote {path.name} ({log_size_mb(path):.0f} MB) in {time.perf_counter() - t0:.1f} s",
                          file=sys.stderr)
                res = run_cases(["bare", "deser", "decode", "info"], path, read_fmt, args.repeat)
                bare, deser, dec, info = res["bare"], res["deser"], res["decode"], res["info"]
                if dec["scans"] != bare["scans"]:
                    raise SystemExit(f"{path.name}: decode gave {dec['scans']} scans, bare {bare['scans']}")
                mb = bare["bytes"] / 1e6
                rows.append({
                    "format": fmt, "duration_s": dur, "scans": dec["scans"], "imu": dec["imu_samples"],
                    "MB": round(mb, 1), "bare_s": round(bare["seconds"], 3), "deser_s": round(deser["seconds"], 3),
                    "decode_s": round(dec["seconds"], 3),
                    "scans_per_s": round(dec["scans"] / dec["seconds"], 1), "MB_per_s": round(mb / dec["seconds"], 1),
                    "ratio": round(dec["seconds"] / bare["seconds"], 3),
                    "bare_peak_MB": round(bare["peak_rss_mb"]), "decode_peak_MB": round(dec["peak_rss_mb"]),
                    "info_s": round(info["seconds"], 4),
                })
                print(f"  {fmt} {dur:g} s done", file=sys.stderr)
    finally:
        if args.workdir is None:
            shutil.rmtree(work, ignore_errors=True)

    cols = ["format", "duration_s", "scans", "MB", "bare_s", "deser_s", "decode_s", "scans_per_s", "MB_per_s",
            "ratio", "bare_peak_MB", "decode_peak_MB", "info_s"]
    head = ["format", "dur s", "scans", "MB", "bare s", "rosbags deser s", "decode s", "scans/s", "MB/s",
            "decode/bare", "bare peak MB", "decode peak MB", "info s"]
    print(f"\nlio read benchmark: {args.beams}x{args.columns} points per scan at 10 Hz, IMU 200 Hz; "
          f"python {sys.version.split()[0]}, {os.cpu_count()} CPUs; goal decode/bare <= 1.25; "
          "peak = max RSS of the process")
    print("| " + " | ".join(head) + " |")
    print("|" + "|".join("---" for _ in head) + "|")
    for r in rows:
        print("| " + " | ".join(f"{r[c]:g}" if isinstance(r[c], float) else str(r[c]) for c in cols) + " |")
    if args.json:
        print(json.dumps(rows, indent=1))


if __name__ == "__main__":
    main()
