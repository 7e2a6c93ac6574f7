#!/usr/bin/env python3
"""`lio fuse` on logs it was not tuned for (issue 27): the robustness matrix, with its baselines per cell.

Cells: platform {rover: a ground robot on uneven ground, car: `drive`, drone: 3D flight; `--platforms` adds
handheld} x start {still, moving} x IMU {aligned (identity rotation, the scenario's lever arm), rotated 180 deg
roll + 90 deg yaw with a 0.44 m lever arm, given by /tf_static} x wheels {exact, 3 % radius scale + 3 slip
bursts} (rover and car) x GPS {none, consumer: `--gps-model consumer`; `--gps` adds rtk: 2 cm fixes, where a roof
antenna's offset shows} x odometry input {none, `lio odom` of the same log}. Seed fixed: 80 cells.

Per cell: `lio fuse` default (smoothed) and `--no-smooth` (the filter; output at every IMU sample, 200 Hz) and
the baselines of the same log: wheel dead reckoning (the /wheel/odom poses), wheel speed + gyro yaw dead
reckoning (a robot_localization 2D user's: x, y, yaw from the wheel speed and the gyro's z about base, its bias
taken from the first second when the log starts at rest), the odometry input alone, the odometry interpolated to the IMU stamps, GPS alone. ATE =
APE translation RMSE after SE(3) alignment against the exact ground truth (lio_cli.evaluation); horizontal ATE
the same fit's east/north error; RPE over 0.05 s.

Targets (issue 27): T1 fused default ATE <= 0.8x the best applicable baseline; T2 with GPS fused horizontal ATE
<= 0.5x GPS alone's; T3 the smoothed default's ATE never worse than the filter's (1 mm slack); T4 with odometry
fused ATE <= the odometry's and RPE 0.05 s <= 0.5x the interpolated odometry's.

Logs are cached in --work: one log without LiDAR (`--no-lidar`) per platform, start, IMU, wheels and GPS, and
one with LiDAR and without wheels per platform, start and IMU for `lio odom` (LiDAR + IMU odometry, so fuse
counts the wheels once; same seed: the IMU messages are the same bytes in both, so its odometry fuses with each
cheap log). A re-run only re-runs fuse.

    python benchmarks/fuse_robustness.py --work /tmp/fuse-rob --jobs 2          # the whole matrix, 45 s logs
    python benchmarks/fuse_robustness.py --work /tmp/fuse-rob --quick            # 12 cells
    python benchmarks/fuse_robustness.py --work /tmp/fuse-rob --cells rover/moving --cells gps-consumer
    python benchmarks/fuse_robustness.py --work /tmp/fuse-rob --hills 2:150     # over hills: rover and car

``--hills A:L`` drives the ground platforms over hills (`lio simulate --hills`, height A sin(2 pi s / L) along the
path): the simulated world's ground is flat, so there is no LiDAR and no `lio odom` cell; the rows also hold the
baselines' horizontal ATE (``wheel_h``, ``wheel_gyro_h``: they are 2D), and the summary counts T1 on horizontal
ATE too (fused_h <= 0.8x the best baseline's horizontal).
"""

from __future__ import annotations

import argparse
import datetime
import itertools
import json
import os
import subprocess
import sys
import time
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))

from lio_cli.evaluation import EvalOptions, evaluate  # noqa: E402
from lio_cli.model.trajectory import Trajectory  # noqa: E402
from lio_cli.geodesy import EnuFrame  # noqa: E402
from lio_cli.geometry import interpolate_poses  # noqa: E402
from lio_cli.io.files.trajectory import read_tum  # noqa: E402
from lio_cli.io.logs.reader import open_log  # noqa: E402

NS = 1_000_000_000
PLATFORMS = {"rover": "rover", "car": "drive", "drone": "drone", "handheld": "handheld"}  # name -> scenario
DEFAULT_PLATFORMS = ("rover", "car", "drone")
STARTS = ("still", "moving")
IMUS = {"imu-aligned": ["--imu-rotation", "0,0,0"],
        "imu-rotated": ["--imu-rotation", "180,0,90", "--imu-lever-arm", "0.3,-0.2,0.25"]}
WHEELS = {"wheels-exact": ["--no-wheel-errors"],
          "wheels-bad": ["--no-wheel-errors", "--wheel-radius-scale", "1.03,1.03", "--wheel-slip-bursts", "3"]}
# rtk (--gps rtk, not in the default matrix): centimetre fixes, whose error a roof antenna's offset would dwarf
GPS = {"gps-none": [], "gps-consumer": ["--gps-model", "consumer"], "gps-rtk": ["--gps", "--gps-noise", "0.02,0.04"]}
DEFAULT_GPS = ("gps-none", "gps-consumer")
ODOMS = ("odom-none", "odom-lio")
SEED = 7
RPE_DT_S = 0.05
EXACT_NS = 1_000_000  # ground truth at 100 Hz: only the IMU stamps that fall on it are paired
SMOOTH_SLACK_M = 0.001
HILLS: str | None = None  # "A:L" for `lio simulate --hills` (--hills)


@dataclass(frozen=True)
class Cell:
    platform: str
    start: str
    imu: str
    wheels: str  # "-" for the handheld
    gps: str
    odom: str

    @property
    def name(self) -> str:
        return "/".join(p for p in (self.platform, self.start, self.imu, self.wheels, self.gps, self.odom) if p != "-")

    @property
    def log_key(self) -> str:  # the cheap log's name
        return "-".join(p for p in (self.platform, self.start, self.imu, self.wheels, self.gps) if p != "-")

    @property
    def lidar_key(self) -> str:
        return f"{self.platform}-{self.start}-{self.imu}-lidar"


def all_cells(quick: bool, platforms: tuple[str, ...] = DEFAULT_PLATFORMS,
              receivers: tuple[str, ...] = DEFAULT_GPS) -> list[Cell]:
    cells = []
    starts, imus = (("moving",), ("imu-rotated",)) if quick else (STARTS, tuple(IMUS))
    for platform, start, imu, gps, odom in itertools.product(platforms, starts, imus, receivers, ODOMS):
        wheels = ("-",) if platform in ("drone", "handheld") else (("wheels-bad",) if quick else tuple(WHEELS))
        cells += [Cell(platform, start, imu, w, gps, odom) for w in wheels]
    return cells


def lio(*args: str) -> tuple[int, str]:
    env = dict(os.environ, PYTHONPATH=str(ROOT))
    p = subprocess.run([sys.executable, "-m", "lio_cli", *map(str, args)], capture_output=True, text=True, env=env)
    return p.returncode, p.stderr.strip().splitlines()[-1] if p.returncode and p.stderr.strip() else ""


def simulate_args(cell: Cell, lidar: bool, duration: float) -> list[str]:
    args = ["--duration", str(duration), "--seed", str(SEED), "--start", cell.start, *IMUS[cell.imu], "--quiet"]
    if HILLS:
        args += ["--hills", HILLS]
    if not lidar:
        return args + ["--no-lidar", *WHEELS.get(cell.wheels, []), *GPS[cell.gps]]
    return args + ["--no-wheel"]  # lio odom from LiDAR and IMU: fuse adds the wheels once, not twice


def ensure_log(work: Path, cell: Cell, lidar: bool, duration: float) -> Path:
    key = cell.lidar_key if lidar else cell.log_key
    out = work / "logs" / f"{key}.mcap"
    if not (out.exists() and out.with_name(f"{key}.truth.json").exists()):
        rc, err = lio("simulate", PLATFORMS[cell.platform], out, *simulate_args(cell, lidar, duration), "--force")
        if rc:
            raise RuntimeError(f"simulate {key}: {err}")
    return out


def ensure_odom(work: Path, lidar_log: Path) -> Path:
    out = work / "odom" / f"{lidar_log.stem}.odom.tum"
    if not out.exists():
        rc, err = lio("odom", lidar_log, "-o", out, "--force", "--quiet")
        if rc:
            raise RuntimeError(f"odom {lidar_log.name}: {err}")
    return out


# --- evaluation (lio's own code) -------------------------------------------------------------------------

def _traj(stamps: np.ndarray, poses: np.ndarray, name: str) -> Trajectory:
    return Trajectory(np.asarray(stamps, np.int64), np.asarray(poses, float), name=name)


def ate(gt: Trajectory, est: Trajectory, translation_only: bool = False) -> tuple[float, float]:
    """(3D ATE, horizontal ATE) after one SE(3) fit on the poses paired exactly with the ground truth."""
    res = evaluate(gt, est, EvalOptions(max_diff_ns=EXACT_NS, translation_only=translation_only))
    d = res.association.ref.poses[:, :3, 3] - res.est_aligned[:, :3, 3]
    return res.stats["ape"]["trans"]["rmse"], float(np.sqrt(np.mean(np.sum(d[:, :2] ** 2, axis=1))))


def rpe(gt: Trajectory, est: Trajectory) -> float:
    res = evaluate(gt, est, EvalOptions(max_diff_ns=EXACT_NS, delta=RPE_DT_S, delta_unit="s"))
    return res.stats["rpe"]["trans"]["rmse"]


# --- baselines -----------------------------------------------------------------------------------------------

def read_log(log: Path) -> dict:
    """The streams the baselines need: wheel poses and speeds, gyro, GPS fixes, /tf_static's base -> imu."""
    imu_t, gyro, wheel_t, wheel_T, wheel_v, gps = [], [], [], [], [], []
    with open_log(log) as lg:
        for topic, _, _, m in lg.messages(["/imu", "/wheel/odom", "/gps/fix"]):
            t = m.header.stamp.sec * NS + m.header.stamp.nanosec
            if topic == "/imu":
                imu_t.append(t)
                gyro.append((m.angular_velocity.x, m.angular_velocity.y, m.angular_velocity.z))
            elif topic == "/wheel/odom":
                p, q = m.pose.pose.position, m.pose.pose.orientation
                yaw = 2.0 * np.arctan2(q.z, q.w)
                T = np.eye(4)
                T[:2, :2] = [[np.cos(yaw), -np.sin(yaw)], [np.sin(yaw), np.cos(yaw)]]
                T[:3, 3] = (p.x, p.y, p.z)
                wheel_t.append(t)
                wheel_T.append(T)
                wheel_v.append(m.twist.twist.linear.x)
            elif m.status.status >= 0:
                gps.append((t, m.latitude, m.longitude, m.altitude))
    return {"imu_t": np.array(imu_t, np.int64), "gyro": np.array(gyro), "wheel_t": np.array(wheel_t, np.int64),
            "wheel_T": np.array(wheel_T), "wheel_v": np.array(wheel_v), "gps": np.array(gps)}


def wheel_gyro_dr(d: dict, R_base_imu: np.ndarray, still: bool) -> Trajectory:
    """x, y, yaw integrated at the IMU rate from the last wheel speed and the gyro's rate about base z."""
    t, w = d["imu_t"], (d["gyro"] @ R_base_imu.T)[:, 2]
    if still:  # a driver or user calibrates the gyro at rest
        w = w - w[t < t[0] + NS].mean()
    k = np.clip(np.searchsorted(d["wheel_t"], t, side="right") - 1, 0, len(d["wheel_t"]) - 1)
    v = np.where(t >= d["wheel_t"][0], d["wheel_v"][k], 0.0)
    dt = np.diff(t) * 1e-9
    yaw = np.concatenate([[0.0], np.cumsum(w[:-1] * dt)])
    mid = yaw[:-1] + 0.5 * w[:-1] * dt
    xy = np.vstack([[0.0, 0.0], np.cumsum(np.column_stack([np.cos(mid), np.sin(mid)]) * (v[:-1] * dt)[:, None], axis=0)])
    T = np.tile(np.eye(4), (len(t), 1, 1))
    T[:, 0, 0], T[:, 0, 1], T[:, 1, 0], T[:, 1, 1] = np.cos(yaw), -np.sin(yaw), np.sin(yaw), np.cos(yaw)
    T[:, :2, 3] = xy
    return _traj(t, T, "wheel+gyro")


def gps_alone(d: dict, truth: dict) -> tuple[Trajectory, Trajectory] | None:
    """(the fixes in ENU, the true antenna track at their stamps as the reference) or None without GPS."""
    if not len(d["gps"]):
        return None
    g = truth["gps"]
    o = g["origin"]
    enu = EnuFrame(o["lat_deg"], o["lon_deg"], o["alt_m"]).to_enu(d["gps"][:, 1], d["gps"][:, 2], d["gps"][:, 3])
    T = np.tile(np.eye(4), (len(enu), 1, 1))
    T[:, :3, 3] = enu
    return _traj(d["gps"][:, 0].astype(np.int64), T, "gps"), np.asarray(g["T_base_gps"])


# --- one cell ------------------------------------------------------------------------------------------------

def run_cell(work: Path, cell: Cell) -> dict:
    log = work / "logs" / f"{cell.log_key}.mcap"
    truth = json.loads(log.with_name(f"{cell.log_key}.truth.json").read_text())
    gt = _traj(*read_tum(log.with_name(f"{cell.log_key}.gt.tum")), "gt")
    odom = work / "odom" / f"{cell.lidar_key}.odom.tum" if cell.odom == "odom-lio" else None
    row: dict = {"cell": cell.name}
    for mode, extra in (("filter", ["--no-smooth"]), ("default", [])):
        out = work / "fuse" / f"{cell.name.replace('/', '-')}.{mode}.tum"
        args = ["fuse", log, "-o", out, "--force", "--quiet", *extra, *(["--odom", odom] if odom else [])]
        t0 = time.perf_counter()
        rc, err = lio(*args)
        row[f"{mode}_wall_s"] = time.perf_counter() - t0
        if rc:
            row[f"{mode}_error"] = f"exit {rc}: {err}  (lio {' '.join(map(str, args))})"
            continue
        est = _traj(*read_tum(out), mode)
        row[mode], row[f"{mode}_h"] = ate(gt, est)
        row[f"{mode}_rpe"] = rpe(gt, est)
        metrics = out.with_name(out.name[: -len(".tum")] + ".fuse.metrics.json")
        if mode == "default" and metrics.exists():
            m = json.loads(metrics.read_text())
            row["estimator"] = m.get("estimator", {}).get("name") if isinstance(m.get("estimator"), dict) else m.get("estimator")
    d = read_log(log)
    if len(d["wheel_t"]):
        row["wheel"], row["wheel_h"] = ate(gt, _traj(d["wheel_t"], d["wheel_T"], "wheel"))
        R_bi = np.asarray(truth["T_base_imu"])[:3, :3]  # what /tf_static holds
        row["wheel_gyro"], row["wheel_gyro_h"] = ate(gt, wheel_gyro_dr(d, R_bi, cell.start == "still"))
    if odom is not None:
        o_t, o_T = read_tum(odom)
        row["odom"] = ate(gt, _traj(o_t, o_T, "odom"))[0]
        at = d["imu_t"][(d["imu_t"] >= o_t[0]) & (d["imu_t"] <= o_t[-1])]
        interp = _traj(at, interpolate_poses(o_t, o_T, at), "odom interpolated")
        row["odom_i"], row["odom_i_rpe"] = ate(gt, interp)[0], rpe(gt, interp)
    g = gps_alone(d, truth)
    if g is not None:
        fixes, T_base_gps = g
        antenna = _traj(gt.stamps_ns, gt.poses @ T_base_gps, "antenna")
        row["gps"], row["gps_h"] = ate(antenna, fixes, translation_only=True)
    return row


def targets(row: dict) -> dict[str, bool | None]:
    """T1..T4 of the module doc: True pass, False fail, None not applicable (or fuse failed: False)."""
    f = row.get("default")
    base = [row[k] for k in ("wheel", "wheel_gyro", "odom", "odom_i", "gps") if row.get(k) is not None]
    t = {"T1": None, "T2": None, "T3": None, "T4": None}
    if base:
        t["T1"] = f is not None and f <= 0.8 * min(base)
    if row.get("gps_h") is not None:
        t["T2"] = f is not None and row["default_h"] <= 0.5 * row["gps_h"]
    t["T3"] = f is not None and row.get("filter") is not None and f <= row["filter"] + SMOOTH_SLACK_M
    if row.get("odom") is not None:
        t["T4"] = f is not None and f <= row["odom"] and row["default_rpe"] <= 0.5 * row["odom_i_rpe"]
    return t


COLUMNS = [("filter", "filter"), ("default", "default"), ("wheel", "wheel"), ("whl+gyro", "wheel_gyro"),
           ("odom", "odom"), ("odom200", "odom_i"), ("gps", "gps"), ("fused_h", "default_h"), ("gps_h", "gps_h"),
           ("rpe.05", "default_rpe"), ("odom200.05", "odom_i_rpe")]


def _num(v: float | None) -> str:
    if v is None:
        return f"{'-':>9}"
    return f"{v:9.3f}" if abs(v) < 1e4 else f"{v:9.1e}"


def table(rows: list[dict]) -> str:
    width = max(len(r["cell"]) for r in rows)
    head = f"{'cell':<{width}} " + " ".join(f"{c:>9}" for c, _ in COLUMNS) + "  T1 T2 T3 T4  estimator"
    lines = [head, "-" * len(head)]
    mark = {True: "ok", False: "XX", None: " -"}
    for r in rows:
        vals = " ".join(_num(r.get(k)) for _, k in COLUMNS)
        t = targets(r)
        lines.append(f"{r['cell']:<{width}} {vals}  " + " ".join(mark[t[k]] for k in ("T1", "T2", "T3", "T4"))
                     + f"  {r.get('estimator') or '-'}")
    return "\n".join(lines)


def summary(rows: list[dict]) -> str:
    out = []
    for k, what in (("T1", "fused <= 0.8x best baseline"), ("T2", "GPS: horizontal <= 0.5x GPS alone"),
                    ("T3", "smoothed default <= filter"), ("T4", "odom: ATE <= odom, RPE 0.05 s <= 0.5x interpolated")):
        res = [targets(r)[k] for r in rows]
        n = sum(v is not None for v in res)
        out.append(f"{k} {what}: {sum(v is True for v in res)}/{n} pass")
    hb = [(r, [r[k] for k in ("wheel_h", "wheel_gyro_h") if r.get(k) is not None]) for r in rows]
    hb = [(r, b) for r, b in hb if b]
    if HILLS and hb:  # the baselines are 2D: over hills their vertical error is the terrain's
        ok = sum(r.get("default_h") is not None and r["default_h"] <= 0.8 * min(b) for r, b in hb)
        out.append(f"T1h horizontal: fused_h <= 0.8x best baseline's horizontal: {ok}/{len(hb)} pass")
    errors = [r[k] for r in rows for k in ("default_error", "filter_error") if k in r]
    out.append(f"fuse failed in {len(errors)} run(s)" + "".join(f"\n  {e}" for e in errors))
    return "\n".join(out)


def main(argv: list[str] | None = None) -> int:
    global SEED, HILLS
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--work", type=Path, default=Path("/tmp/lio-fuse-robustness"), help="cache of logs, odometry, fuse outputs")
    ap.add_argument("--quick", action="store_true", help="moving starts, rotated IMU, bad wheels only (12 cells)")
    ap.add_argument("--platforms", default=",".join(DEFAULT_PLATFORMS), help=f"comma-separated, of {', '.join(PLATFORMS)}")
    ap.add_argument("--gps", default=",".join(g[4:] for g in DEFAULT_GPS),
                    help="comma-separated, of none, consumer, rtk (2 cm fixes; not in the default matrix)")
    ap.add_argument("--cells", action="append", default=[], help="keep cells whose name holds this (repeat: all of them)")
    ap.add_argument("--duration", type=float, default=45.0, help="seconds per log (cached logs of another length are remade)")
    ap.add_argument("--jobs", type=int, default=1)
    ap.add_argument("--seed", type=int, default=SEED, help=f"simulation seed (default {SEED}; another seed: a held-out check)")
    ap.add_argument("--json", type=Path, help="also write the rows here")
    ap.add_argument("--hills", metavar="A:L", help="over hills (lio simulate --hills A:L): rover and car, no odometry")
    a = ap.parse_args(argv)
    SEED, HILLS = a.seed, a.hills
    work = a.work / (f"{a.duration:g}s" + ("" if a.seed == 7 else f"-seed{a.seed}")
                     + (f"-hills{a.hills.replace(':', 'x')}" if a.hills else ""))  # the cache is per seed and terrain
    for sub in ("logs", "odom", "fuse"):
        (work / sub).mkdir(parents=True, exist_ok=True)
    platforms = tuple(a.platforms.split(","))
    if not set(platforms) <= set(PLATFORMS):
        print(f"--platforms: choose from {', '.join(PLATFORMS)}", file=sys.stderr)
        return 2
    gps = tuple(f"gps-{g}" for g in a.gps.split(","))
    if not set(gps) <= set(GPS):
        print("--gps: choose from none, consumer, rtk", file=sys.stderr)
        return 2
    if a.hills:  # the simulated world's ground is flat: no LiDAR, so no odometry cell; ground platforms only
        platforms = tuple(p for p in platforms if p in ("rover", "car"))
    cells = [c for c in all_cells(a.quick, platforms, gps) if all(s in c.name for s in a.cells)
             and not (a.hills and c.odom == "odom-lio")]
    if not cells:
        print("no cell matches", file=sys.stderr)
        return 2
    t0 = time.perf_counter()
    with ThreadPoolExecutor(max(1, a.jobs)) as pool:
        cheap = {c.log_key: c for c in cells}
        lidar = {c.lidar_key: c for c in cells if c.odom == "odom-lio"}
        jobs = [pool.submit(ensure_log, work, c, False, a.duration) for c in cheap.values()]
        jobs += [pool.submit(lambda c: ensure_odom(work, ensure_log(work, c, True, a.duration)), c) for c in lidar.values()]
        for j in jobs:
            j.result()
        t_prep = time.perf_counter() - t0
        rows = list(pool.map(lambda c: run_cell(work, c), cells))
    wall = time.perf_counter() - t0
    commit = subprocess.run(["git", "-C", str(ROOT), "rev-parse", "--short", "HEAD"], capture_output=True, text=True).stdout.strip()
    print(f"lio fuse robustness matrix, {datetime.datetime.now(datetime.timezone.utc):%Y-%m-%d %H:%M} UTC, "
          f"commit {commit}, {a.duration:g} s logs, seed {SEED}" + (f", hills {HILLS}" if HILLS else "")
          + f", {len(cells)} cells; ATE m (SE(3) fit), "
          f"_h horizontal, .05 RPE over 0.05 s")
    print(table(rows))
    print(summary(rows))
    print(f"wall {wall:.0f} s (logs and odometry {t_prep:.0f} s, cached ones free), --jobs {a.jobs}")
    if a.json:
        a.json.write_text(json.dumps(rows, indent=1, default=float))
    return 0


if __name__ == "__main__":
    sys.exit(main())
