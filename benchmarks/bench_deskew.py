#!/usr/bin/env python3
"""`lio deskew`: point accuracy per motion source, what it does for kiss-icp, speed, writing cost, memory.

1. Accuracy. Simulates the handheld scenario (16 beams, 1024 columns, ROS 1 bag; --scenario drive or corridor
   instead) and de-skews it with every
   motion source. Each valid point of each scan is compared with the truth: the measured point moved with the
   scenario's analytic motion into the sensor frame at the reference instant (`TrueMotion`). Median and 95th
   percentile of the point error, beside the raw skew (the raw point against the same truth).
2. kiss-icp (`kiss_icp_pipeline`, defaults) on the raw log (its own constant-velocity deskew on, and off) and,
   with its deskew off, on the log de-skewed from the IMU. kiss-icp's poses (LiDAR frame) are moved to the
   base with the true extrinsic and scored against the exact motion at their own instants: on the raw log
   kiss-icp de-skews to the sweep's middle (its timestamps run 0..1, mid_pose_timestamp 0.5), so its pose is
   the middle's; on the de-skewed log the clouds are at the sweep's end, the record time. ATE = SE(3)-aligned
   translation RMSE (lio's evaluation, evo's definition).
3. Speed: each source in its own process: wall and CPU seconds and x real time (CPU seconds count every
   thread and the writing process beside the odometry, so they stand for a machine whose cores are busy with
   other work), with Python's bytecode cache written as on any installed machine. The IMU source is also timed
   on the other scenarios' 16-beam logs (`--speed-scenarios`, default corridor and drive), beside `lio odom`
   alone on each: the odometry is what a run from the IMU cannot go below.
   Writing: the output's records written from memory by rosbags' Writer alone against lio's LogWriter (same
   bytes, same connections). Memory: peak RSS of `lio deskew` on a log and on one 3x longer (and of its
   writing process, which reports its own).

    python benchmarks/bench_deskew.py                    # 30 s handheld; memory 30 s vs 90 s
    python benchmarks/bench_deskew.py --duration 20 --no-kiss --no-memory --speed-scenarios ""
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
from lio_cli.geometry import inv_pose
from lio_cli.io.messages.pointcloud import decode_pointcloud2
from lio_cli.io.logs.reader import open_log
from lio_cli.io.files.trajectory import read_tum
from lio_cli.model.trajectory import Trajectory
from lio_cli.simulation.deskew_truth import TrueMotion
from lio_cli.simulation.run import simulate

BIN = Path(sys.executable).parent
LIDAR = "/points"


def run(cmd: list[str], cwd: Path) -> dict:
    """Wall s, CPU s (user + system) and peak RSS MB of one command in its own process.

    Measured by GNU time around the command: a forked child's own ru_maxrss would count the benchmark's memory
    it inherited until its exec."""
    stats = cwd / ".time"
    t0 = time.perf_counter()
    proc = subprocess.run(["/usr/bin/time", "-f", "%U %S %M", "-o", str(stats), *cmd], cwd=cwd,
                          stdout=subprocess.DEVNULL, stderr=subprocess.PIPE)
    wall = time.perf_counter() - t0
    err = proc.stderr.decode(errors="replace")
    if proc.returncode != 0:
        print(f"  ! {' '.join(cmd[:3])} exited {proc.returncode}: {err.strip().splitlines()[-1] if err.strip() else ''}",
              file=sys.stderr)
    user, system, rss_kb = stats.read_text().split()[-3:]
    return {"wall_s": wall, "cpu_s": float(user) + float(system), "peak_mb": int(rss_kb) / 1024.0,
            "code": proc.returncode}


def point_errors(truth: TrueMotion, raw: Path, out: Path) -> tuple[np.ndarray, np.ndarray]:
    """(|de-skewed - true|, |raw - true|) over every valid point."""
    with open_log(raw) as a, open_log(out) as b:
        pairs = zip((m for _, _, _, m in a.messages([LIDAR], fast=True)), (m for _, _, _, m in b.messages([LIDAR], fast=True)))
        err, skew = [], []
        for ma, mb in pairs:
            ca, cb = decode_pointcloud2(ma), decode_pointcloud2(mb)
            true = truth.deskewed(ca.points, ca.point_stamps_ns, cb.stamp_ns)
            err.append(np.linalg.norm(cb.points - true, axis=1))
            skew.append(np.linalg.norm(ca.points - true, axis=1))
    return np.concatenate(err), np.concatenate(skew)


def lio_deskew(log: Path, out: Path, work: Path, *args: str) -> dict:
    res = run([str(BIN / "lio"), "deskew", str(log), str(out), "-q", "--force", *args], work)
    metrics = out.with_name(out.name.removesuffix(".bag") + ".deskew.metrics.json")
    res["metrics"] = json.loads(metrics.read_text()) if res["code"] == 0 else None
    return res


def accuracy(work: Path, log: Path, gt: Path, truth: TrueMotion, duration: float) -> list[dict]:
    rows = []
    odom = run([str(BIN / "lio"), "odom", str(log), "-o", str(work / "odom.tum"), "-q", "--force"], work)
    sources = [
        ("trajectory: ground truth (100 Hz)", ["--trajectory", str(gt)], None),
        ("trajectory: lio odom TUM, cubic", ["--trajectory", str(work / "odom.tum")], odom),
        ("trajectory: lio odom TUM, linear", ["--trajectory", str(work / "odom.tum"), "--config",
                                              str(_config(work, "trajectory:\n  interpolation: linear\n"))], odom),
        ("imu (odometry + gyro)", [], None),
        ("constant-velocity (LiDAR-only odometry)", ["--motion", "constant-velocity"], None),
    ]
    for k, (name, args, before) in enumerate(sources):
        out = work / f"deskewed_{k}.bag"
        res = lio_deskew(log, out, work, *args)
        row = {"source": name, "log_s": duration, **{key: res[key] for key in ("wall_s", "cpu_s", "peak_mb")}}
        if before is not None:  # the odometry run that made the trajectory counts too
            row["wall_s"] += before["wall_s"]
            row["cpu_s"] += before["cpu_s"]
        if res["code"] == 0:
            err, skew = point_errors(truth, log, out)
            m = res["metrics"]
            row.update(median_mm=np.median(err) * 1e3, p95_mm=np.percentile(err, 95) * 1e3, max_mm=err.max() * 1e3,
                       skew_median_mm=np.median(skew) * 1e3, skew_p95_mm=np.percentile(skew, 95) * 1e3,
                       skew_max_m=skew.max(), deskewed=m["scans"]["deskewed"], scans=m["scans"]["total"],
                       write_pass_s=m["time_s"]["write_pass"], writing=m.get("writing"))
        rows.append(row)
        print(f"  {name}: done", file=sys.stderr)
    return rows


def _config(work: Path, text: str) -> Path:
    path = work / "linear.yaml"
    path.write_text(text)
    return path


def kiss(work: Path, raw: Path, deskewed: Path, truth: TrueMotion, period_s: float, columns: int) -> list[dict]:
    """kiss-icp ATE on the raw log (deskew on / off) and on the de-skewed log (deskew off)."""
    off = work / "kiss_no_deskew.yaml"
    off.write_text("data:\n  deskew: false\n")
    cases = [("raw log, kiss-icp deskew on (default)", raw, None, -0.5 * period_s),
             ("raw log, kiss-icp deskew off", raw, off, -0.5 * period_s),
             ("lio deskew (imu) log, kiss-icp deskew off", deskewed, off, -period_s / columns)]
    rows = []
    for k, (name, log, cfg, shift_s) in enumerate(cases):
        d = work / f"kiss_{k}"
        shutil.rmtree(d, ignore_errors=True)
        d.mkdir()
        cmd = [str(BIN / "kiss_icp_pipeline"), "--topic", LIDAR, str(log)] + (["--config", str(cfg)] if cfg else [])
        res = run(cmd, d)
        found = sorted((d / "results").glob("*/*_tum.txt"))
        ate = None
        if res["code"] == 0 and found:
            stamps, P = read_tum(found[-1])
            stamps = stamps + int(round(shift_s * 1e9))  # the instant each pose is of
            T_bl = truth.T_base_lidar
            est = Trajectory(stamps, T_bl[None] @ P @ inv_pose(T_bl)[None], "kiss-icp")
            ref = Trajectory(stamps, truth.poses(stamps), "truth")
            ate = evaluate(ref, est, EvalOptions(max_diff_ns=1)).stats["ape"]["trans"]["rmse"]
        rows.append({"case": name, "ate_m": ate, "wall_s": res["wall_s"]})
        print(f"  kiss-icp {name}: ATE {ate}", file=sys.stderr)
    return rows


def writer_cost(work: Path, out_fmt: str, src: Path) -> dict:
    """Seconds to write ``src``'s records from memory: rosbags' Writer alone vs lio's LogWriter."""
    from lio_cli.io.logs.writer import LogWriter

    with open_log(src) as r:
        conns = r.connections
        recs = [(rec.connection.key, rec.log_time_ns, bytes(rec.data)) for rec in r.records()]
    by_key = {c.key: c for c in conns}
    suffix = ".bag" if out_fmt == "ros1" else ""
    times = {}
    for tool in ("rosbags", "lio") * 5:  # taking turns, best of five
        path = work / f"w_{tool}{suffix}"
        shutil.rmtree(path, ignore_errors=True)
        path.unlink(missing_ok=True)
        t0 = time.perf_counter()
        if tool == "rosbags":
            if out_fmt == "ros1":
                from rosbags.rosbag1 import Writer

                w = Writer(path)
                w.open()
                out = {k: w.add_connection(c.topic, c.msgtype, msgdef=c.msgdef, md5sum=c.digest, callerid=c.callerid,
                                           latching=c.latching) for k, c in by_key.items()}
            else:
                from rosbags.rosbag2 import Writer

                w = Writer(path, version=8)
                w.open()
                out = {k: w.add_connection(c.topic, c.msgtype, msgdef=c.msgdef, rihs01=c.digest) for k, c in by_key.items()}
            for key, t, data in recs:
                w.write(out[key], t, data)
            w.close()
        else:
            with LogWriter(path, out_fmt) as w:
                out = {k: w.add_mirror(c) for k, c in by_key.items()}
                for key, t, data in recs:
                    w.write_record(out[key], t, data)
        dt = time.perf_counter() - t0
        times[tool] = min(times.get(tool, dt), dt)
    return {"format": out_fmt, "messages": len(recs), "rosbags_s": times["rosbags"], "lio_s": times["lio"]}


def other_scenarios(work: Path, scenarios: list[str], duration: float, seed: int) -> list[dict]:
    """Speed from the IMU on other 16-beam logs of the same length, beside `lio odom` alone on each (the
    odometry is the floor: the writing runs beside it)."""
    rows = []
    for name in scenarios:
        d = work / f"speed_{name}"
        d.mkdir(exist_ok=True)
        sim = simulate(name, d / "log.bag", "ros1", duration_s=duration, seed=seed, force=True, beams=16)
        odom = run([str(BIN / "lio"), "odom", str(sim.log_path), "-o", str(d / "odom.tum"), "-q", "--force"], d)
        r = lio_deskew(sim.log_path, d / "out.bag", d)
        err, _ = point_errors(TrueMotion(sim.truth_path), sim.log_path, d / "out.bag")
        m = r["metrics"]
        rows.append({"scenario": name, "log_s": duration, "wall_s": r["wall_s"], "cpu_s": r["cpu_s"],
                     "odom_wall_s": odom["wall_s"], "median_mm": np.median(err) * 1e3,
                     "p95_mm": np.percentile(err, 95) * 1e3, "register_s": m["motion"]["odometry"]["time_s"],
                     "writing": m["writing"]})
        print(f"  speed {name}: done", file=sys.stderr)
    return rows


def memory(work: Path, scenario: str, durations: tuple[float, float], seed: int) -> list[dict]:
    rows = []
    for dur in durations:
        d = work / f"mem_{dur:.0f}"
        d.mkdir(exist_ok=True)
        res = simulate(scenario, d / "h.bag", "ros1", duration_s=dur, seed=seed, force=True)
        for name, args in (("trajectory", ["--trajectory", str(res.gt_path)]), ("imu", [])):
            r = lio_deskew(res.log_path, d / f"out_{name}.bag", d, *args)
            helper = r["metrics"].get("helper_peak_rss_mb") if r["metrics"] else None
            rows.append({"log_s": dur, "source": name, "peak_mb": r["peak_mb"], "helper_mb": helper,
                         "wall_s": r["wall_s"], "cpu_s": r["cpu_s"], "log_mb": res.log_path.stat().st_size / 2**20})
        print(f"  memory {dur:.0f} s: done", file=sys.stderr)
    return rows


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--duration", type=float, default=30.0)
    ap.add_argument("--scenario", default="handheld", choices=("handheld", "drive", "corridor"))
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--no-kiss", action="store_true")
    ap.add_argument("--no-memory", action="store_true")
    ap.add_argument("--speed-scenarios", default="corridor,drive",
                    help="also time the IMU source on these scenarios' 16-beam logs ('' for none)")
    ap.add_argument("--keep", type=Path, default=None, help="keep logs and outputs in this folder")
    ap.add_argument("--json", type=Path, default=None)
    args = ap.parse_args()
    use_bytecode_cache()
    work = args.keep or Path(tempfile.mkdtemp(prefix="lio-bench-deskew-"))
    work.mkdir(parents=True, exist_ok=True)
    t0 = time.perf_counter()
    sim = simulate(args.scenario, work / f"{args.scenario}.bag", "ros1", duration_s=args.duration, seed=args.seed,
                   force=True)
    print(f"simulated {args.duration:.0f} s in {time.perf_counter() - t0:.1f} s", file=sys.stderr)
    truth = TrueMotion(sim.truth_path)
    results = {"accuracy": accuracy(work, sim.log_path, sim.gt_path, truth, args.duration)}
    if not args.no_kiss:
        info = json.loads(sim.truth_path.read_text())["lidar"]
        results["kiss"] = kiss(work, sim.log_path, work / "deskewed_3.bag", truth, info["period_s"], info["columns"])
    others = [x for x in args.speed_scenarios.split(",") if x and x != args.scenario]
    if others:
        results["speed"] = other_scenarios(work, others, args.duration, args.seed)
    ros2 = work / "deskewed_ros2"
    lio_deskew(sim.log_path, ros2, work, "--trajectory", str(sim.gt_path), "--format", "ros2")
    results["writer"] = [writer_cost(work, "ros1", work / "deskewed_0.bag"), writer_cost(work, "ros2", ros2)]
    if not args.no_memory:
        results["memory"] = memory(work, args.scenario, (args.duration, 3 * args.duration), args.seed)
    print_tables(results, args.scenario, os.getloadavg()[0])
    if args.json:
        args.json.write_text(json.dumps(results, indent=2, default=float))
    return 0


def _f(v, fmt: str) -> str:
    return "-" if v is None else format(v, fmt)


def print_tables(r: dict, scenario: str, load: float) -> None:
    print(f"\nAccuracy and speed per motion source ({scenario}; load average {load:.1f} on this machine)\n")
    print("| motion source | median mm | p95 mm | max mm | raw skew median / p95 mm (max m) | scans de-skewed | "
          "wall s | x real time (wall) | CPU s | x real time (CPU) |")
    print("|---|---|---|---|---|---|---|---|---|---|")
    for a in r["accuracy"]:
        print(f"| {a['source']} | {_f(a.get('median_mm'), '.2f')} | {_f(a.get('p95_mm'), '.2f')} | "
              f"{_f(a.get('max_mm'), '.1f')} | {_f(a.get('skew_median_mm'), '.0f')} / {_f(a.get('skew_p95_mm'), '.0f')} "
              f"({_f(a.get('skew_max_m'), '.1f')}) | {a.get('deskewed', '-')}/{a.get('scans', '-')} | {a['wall_s']:.1f} | "
              f"{a['log_s'] / a['wall_s']:.1f} | {a['cpu_s']:.1f} | {a['log_s'] / a['cpu_s']:.1f} |")
    for a in r["accuracy"]:
        if a.get("writing"):
            print(f"\n{a['source']}: written {a['writing']}")
    if "speed" in r:
        print("\nFrom the IMU on other 16-beam logs of the same length (1024 columns; `lio odom` alone beside)\n")
        print("| scenario | median mm | p95 mm | wall s | x real time (wall) | CPU s | lio odom alone wall s | "
              "odometry inside s |")
        print("|---|---|---|---|---|---|---|---|")
        for a in r["speed"]:
            print(f"| {a['scenario']} | {a['median_mm']:.2f} | {a['p95_mm']:.2f} | {a['wall_s']:.1f} | "
                  f"{a['log_s'] / a['wall_s']:.1f} | {a['cpu_s']:.1f} | {a['odom_wall_s']:.1f} | {a['register_s']:.1f} |")
    if "kiss" in r:
        print("\nkiss-icp on the raw and the de-skewed log (ATE: SE(3)-aligned translation RMSE against the exact motion)\n")
        print("| kiss-icp run | ATE m | wall s |")
        print("|---|---|---|")
        for k in r["kiss"]:
            print(f"| {k['case']} | {_f(k['ate_m'], '.3f')} | {k['wall_s']:.1f} |")
    print("\nWriting the de-skewed log's records from memory (best of five)\n")
    print("| format | messages | rosbags Writer alone s | lio LogWriter s | lio / rosbags |")
    print("|---|---|---|---|---|")
    for w in r["writer"]:
        print(f"| {w['format']} | {w['messages']} | {w['rosbags_s']:.3f} | {w['lio_s']:.3f} | "
              f"{w['lio_s'] / w['rosbags_s']:.2f} |")
    if "memory" in r:
        print("\nPeak memory of `lio deskew` (whole process; with the IMU, also its writing process beside it)\n")
        print("| log s | log MB | motion source | peak MB | writing process peak MB | wall s | CPU s |")
        print("|---|---|---|---|---|---|---|")
        for m in r["memory"]:
            print(f"| {m['log_s']:.0f} | {m['log_mb']:.0f} | {m['source']} | {m['peak_mb']:.0f} | "
                  f"{_f(m.get('helper_mb'), '.0f')} | {m['wall_s']:.1f} | {m['cpu_s']:.1f} |")


if __name__ == "__main__":
    sys.exit(main())
