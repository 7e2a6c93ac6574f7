#!/usr/bin/env python3
"""`lio calibrate` end to end (the job the command runs: read the log, LiDAR-only then gyro-primed odometry, the
estimators) on `lio simulate` logs against their truth.json; prints the issue's target table.

Every log is simulated WITHOUT /tf_static (--no-tf-static), so nothing the estimates fall back to knows the
truth: the LiDAR is the base and T_base_imu is compared with the true T_lidar_imu. Rows:
  time offset     handheld logs, IMU clock offsets 5..100 ms of either sign, two families of mountings (20 logs)
  rotation / translation, handheld   the same logs
  tilted handheld  the same logs with --tilt-scale 3 (pitch +-14 deg, roll +-10 deg: the tilting calibrate asks
                   for when the vertical lever arm is not observable): translation on all axes
  rotation, driving                  drive logs (yaw of the car observable; roll/pitch of the mounting are not)
  Allan           a 2 h static IMU log (--allan): white noise and random walk, axes averaged
  wheel scales    planar logs with wheel radius/baseline errors and a slip episode
  run time        calibrate on a 40 s handheld log (wall, this machine, whatever its load)
  end to end      lio odom --calib on a 40 s handheld log without /tf_static: the estimated calibration (with
                  T_base_lidar given, as from a drawing) against the true one (extrinsics, clock offset), ATE ratio

  python benchmarks/bench_calibrate.py                  # everything (about 15-25 min on 2 busy cores)
  python benchmarks/bench_calibrate.py --quick          # fewer offsets, shorter logs, 20 min Allan log
"""

from __future__ import annotations

import argparse
import json
import os
import tempfile
import time
from pathlib import Path

import numpy as np

from lio_cli.config.calibrate import CalibrateConfig
from lio_cli.config.odom import OdomConfig
from lio_cli.errors import LioError
from lio_cli.geometry import inv_pose, so3_log
from lio_cli.jobs.calibrate.job import CalibrateJob, run_calibrate
from lio_cli.jobs.contract import load_reference
from lio_cli.jobs.odom.job import OdomJob, run_odom, score_odom
from lio_cli.model.calibration import Calibration
from lio_cli.simulation.run import simulate

OFFSETS_MS = (5, 10, 20, 50, 100)


def truth(sim) -> dict:
    return json.loads(Path(sim.truth_path).read_text())


def true_T_lidar_imu(t: dict) -> np.ndarray:
    return inv_pose(np.array(t["T_base_lidar"])) @ np.array(t["T_base_imu"])


def errors(cal: Calibration, t: dict) -> tuple[np.ndarray, np.ndarray, float]:
    """(rotation error about the LiDAR axes deg, translation error cm, offset error ms); base = LiDAR here."""
    T, Tt = cal.matrix("T_base_imu"), true_T_lidar_imu(t)
    rot = np.degrees(so3_log(T[:3, :3] @ Tt[:3, :3].T))
    return rot, 100 * (T[:3, 3] - Tt[:3, 3]), 1e3 * (cal.imu_time_offset_s - t["imu"]["imu_time_offset_s"])


def med_worst(x) -> str:
    x = np.abs(np.asarray(x, float))
    return f"{np.median(x):.3g} / {x.max():.3g}"


def row(rows, quantity, runs, error, goal, ok) -> None:
    rows.append((quantity, runs, error, goal, "yes" if ok else "NO"))


def calibrate(log: Path, out: Path, cfg: CalibrateConfig | None = None, cpu: list | None = None):
    t0, c0 = time.perf_counter(), time.process_time()
    r = run_calibrate(CalibrateJob(log, out, cfg or CalibrateConfig(), force=True))
    if cpu is not None:
        cpu.append(time.process_time() - c0)
    return r, time.perf_counter() - t0


def walks(offsets) -> list[tuple[int, int, int, int, tuple]]:
    """(family, offset ms, sign, seed, (IMU rotation deg, lever arm m)) of the handheld logs: two families of
    mountings, each offset of either sign."""
    out = []
    for i, ms in enumerate(offsets):
        for sign in (1, -1):
            out.append((0, ms, sign, 100 + i + 10 * (sign > 0), ((5.0, -8.0, 30.0 + 20 * i), (0.15, -0.1, 0.05))))
            out.append((1, ms, sign, 200 + i + 10 * (sign > 0), ((-4.0, 6.0, -20.0 - 25 * i), (-0.1, 0.12, -0.04))))
    return out


def bench_handheld(root: Path, offsets, duration: float, rows: list, tilt: float = 1.0) -> None:
    off_err, rot_err, rot_obs, lev_err, lev_all, failed = [], [], [], [], [], []
    for family, ms, sign, seed, mount in walks(offsets):
        off = -sign * ms * 1e-3  # added to IMU stamps to put them on the LiDAR's clock
        sim = simulate("handheld", root / f"hand_{family}_{ms}_{sign}.bag", "ros1", duration_s=duration, seed=seed,
                       imu_time_offset_s=off, imu_rotation_deg=mount[0], imu_lever_arm_m=mount[1], tf_static=False,
                       tilt_scale=tilt, force=True)
        t = truth(sim)
        try:
            r, _ = calibrate(sim.log_path, root / "c.yaml")
        except LioError as err:
            failed.append(f"{-ms * sign:+d} ms: {err}")
            continue
        rot, lev, e_ms = errors(r.calibration, t)
        off_err.append(e_ms)
        rot_err.append(np.linalg.norm(rot))
        lev_err.append(np.linalg.norm(lev[:2]))
        lev_all.append(np.linalg.norm(lev))
        obs = r.metrics["estimators"]["lever_arm"]["observable"] if "lever_arm" in r.metrics["estimators"] else [1, 1, 1]
        rot_obs.append(np.linalg.norm(lev[np.asarray(obs, bool)]) if any(obs) else np.nan)
        os.remove(sim.log_path)
    n = len(off_err)
    e = np.abs(off_err)
    if tilt != 1.0:
        name = f"handheld {duration:.0f} s tilted (--tilt-scale {tilt:g})"
        row(rows, f"rotation, {name}", f"{n} logs" + (f" ({len(failed)} refused)" if failed else ""),
            f"{med_worst(rot_err)} deg", "<= 0.2 deg", max(rot_err) <= 0.2)
        row(rows, f"translation, {name} (all axes)", f"{n} logs", f"{med_worst(lev_all)} cm", "<= 2 cm",
            max(lev_all) <= 2.0)
        for f in failed:
            print("refused:", f)
        return
    row(rows, f"time offset, handheld {duration:.0f} s, +-5..100 ms", f"{n} logs" + (f" ({len(failed)} refused)" if failed else ""),
        f"median {np.median(e):.3f} ms, worst {e.max():.3f} ms", "<= 0.5 / 1 ms", np.median(e) <= 0.5 and e.max() <= 1.0)
    row(rows, f"rotation, handheld {duration:.0f} s (all axes)", f"{n} logs", f"{med_worst(rot_err)} deg", "<= 0.2 deg",
        max(rot_err) <= 0.2)
    row(rows, f"translation, handheld {duration:.0f} s (x, y)", f"{n} logs", f"{med_worst(lev_err)} cm", "<= 2 cm",
        max(lev_err) <= 2.0)
    row(rows, f"translation, handheld {duration:.0f} s (axes it calls observable)", f"{n} logs",
        f"{med_worst(np.nan_to_num(rot_obs))} cm", "<= 2 cm", np.nanmax(rot_obs) <= 2.0)
    for f in failed:
        print("refused:", f)


def bench_drive(root: Path, seeds: int, duration: float, rows: list) -> None:
    obs_err, yaw_err, notes = [], [], []
    for s in range(seeds):
        sim = simulate("drive", root / f"drive_{s}.mcap", "mcap", duration_s=duration, seed=300 + s, imu_time_offset_s=-0.01,
                       imu_rotation_deg=(2.0, -3.0, 90.0), tf_static=False, force=True)
        t = truth(sim)
        try:
            r, _ = calibrate(sim.log_path, root / "c.yaml")
            how = "offset estimated"
        except LioError as err:  # a car cannot always time its IMU: give the clock offset, as the message says
            notes.append(str(err).split(": ", 1)[1][:90])
            cfg = CalibrateConfig(prior=Calibration(imu_time_offset_s=t["imu"]["imu_time_offset_s"]))
            r, _ = calibrate(sim.log_path, root / "c.yaml", cfg)
            how = "offset given"
        rot, _, _ = errors(r.calibration, t)
        est = r.metrics["estimators"]
        obs = np.asarray(est["rotation"]["observable"], bool)
        if "lever_arm" in est:
            sig = np.asarray(est["lever_arm"]["rotation_sigma_rad"], float)
            obs |= np.isfinite(sig) & (sig <= np.radians(1.0))
        obs_err.append(np.abs(rot[obs]).max() if obs.any() else np.nan)
        yaw_err.append(abs(rot[2]))
        os.remove(sim.log_path)
    row(rows, f"rotation, driving {duration:.0f} s (observable axes; {how})", f"{seeds} logs",
        f"{med_worst(obs_err)} deg (about LiDAR z: {med_worst(yaw_err)} deg)", "<= 0.5 deg", np.nanmax(obs_err) <= 0.5)
    for n in notes:
        print("drive, offset refused:", n)


def bench_wheels(root: Path, seeds: int, duration: float, rows: list) -> None:
    ev, ew = [], []
    for s in range(seeds):
        rng = np.random.default_rng(400 + s)
        sl, sr, bs = 1 + rng.normal(0, 0.01), 1 + rng.normal(0, 0.01), 1 + rng.normal(0, 0.03)
        sim = simulate("planar", root / f"planar_{s}.mcap", "mcap", duration_s=duration, seed=400 + s,
                       imu_time_offset_s=-0.02, wheel_radius_scale=(sl, sr), wheel_baseline_scale=bs, tf_static=False, force=True)
        t = truth(sim)
        w = t["wheel"]
        # the LiDAR's place on the base (a drawing) is needed: the wheels move the base, the LiDAR rides beside it
        cfg = CalibrateConfig(wheel_radius_m=w["radius_m_nominal"], wheel_baseline_m=w["baseline_m_nominal"],
                              prior=Calibration(T_base_lidar=t["T_base_lidar"]))
        try:
            r, _ = calibrate(sim.log_path, root / "c.yaml", cfg)
        except LioError:
            cfg = cfg.model_copy(update={"prior": Calibration(T_base_lidar=t["T_base_lidar"], imu_time_offset_s=-0.02)})
            r, _ = calibrate(sim.log_path, root / "c.yaml", cfg)
        s_v = 0.5 * (sl + sr)
        ev.append(100 * (r.calibration.wheel.speed_scale / s_v - 1))
        ew.append(100 * (r.calibration.wheel.yaw_rate_scale / (s_v / bs) - 1))
        os.remove(sim.log_path)
    for name, e in (("speed", ev), ("yaw-rate", ew)):
        e = np.abs(e)
        row(rows, f"wheel {name} scale, planar {duration:.0f} s + slip", f"{seeds} logs",
            f"{med_worst(e)} % (rms {np.sqrt(np.mean(e**2)):.3f} %)", "<= 0.3 %", max(e) <= 0.3)


def bench_allan(root: Path, hours: float, rows: list) -> None:
    sim = simulate("static", root / "static.mcap", "mcap", duration_s=hours * 3600, seed=500, force=True)
    t = truth(sim)["imu"]
    r, wall = calibrate(sim.log_path, root / "s.yaml", CalibrateConfig(allan=True))
    n = r.calibration.imu_noise
    for name, est, true in (("gyro white noise", n.gyro_noise_radps, t["gyro_noise_density"]),
                            ("gyro random walk", n.gyro_bias_walk, t["gyro_bias_walk"]),
                            ("accel white noise", n.accel_noise_mps2, t["accel_noise_density"]),
                            ("accel random walk", n.accel_bias_walk, t["accel_bias_walk"])):
        e = 100 * (est / true - 1)
        row(rows, f"Allan {name}, {hours:g} h static", f"truth {true:.3g}", f"{e:+.1f} %", "within 10 %", abs(e) <= 10)
    ts = r.metrics["time_s"]
    row(rows, f"Allan run time, {hours:g} h at 200 Hz", "", f"{wall:.1f} s (read {ts['read']:.1f}, Allan {ts['allan']:.1f})",
        "seconds", wall < 60)
    os.remove(sim.log_path)


DRAWS_US = (-2, -1, 0, 1, 2)  # clock offsets added to each calibration: the odometry's draws around it


def bench_end_to_end(root: Path, duration: float, rows: list, seeds: int = 3) -> None:
    """Run time on the first log; the odom --calib ATE ratio on each. One run's ATE is a draw: the same odometry
    moves by 20 % of its ATE when the clock offset it is given changes by a microsecond. So each calibration
    also runs with its offset moved by -2..+2 us, and the medians of those five ATEs are compared too."""
    ratios, first = [], None
    for s in range(seeds):
        sim = simulate("handheld", root / f"e2e_{s}.bag", "ros1", duration_s=duration, seed=600 + s,
                       imu_time_offset_s=0.03 - 0.02 * s, imu_rotation_deg=(10.0, -5.0, 30.0 + 40 * s),
                       imu_lever_arm_m=(0.1, -0.05, 0.08), tf_static=False, force=True)
        t = truth(sim)
        # the LiDAR's place on the base is known (a drawing), the IMU's and its clock are what is calibrated
        prior = CalibrateConfig(prior=Calibration(T_base_lidar=t["T_base_lidar"]))
        cpu: list = []
        r, wall = calibrate(sim.log_path, root / "e2e.calib.yaml", prior, cpu)
        if first is None:
            first = (wall, cpu[0], r.metrics["time_s"])
        true_cal = Calibration(T_base_imu=t["T_base_imu"], T_base_lidar=t["T_base_lidar"],
                               imu_time_offset_s=t["imu"]["imu_time_offset_s"])
        ate = {}
        for name, cal in (("estimated", r.calibration), ("true", true_cal)):
            fields = cal.model_dump(exclude_none=True)
            ate[name] = []
            for d in DRAWS_US:
                moved = {**fields, "imu_time_offset_s": fields.get("imu_time_offset_s", 0.0) + d * 1e-6}
                cfg = OdomConfig(calibration=Calibration.model_validate(moved))
                res = run_odom(OdomJob(sim.log_path, cfg))
                score_odom(res, load_reference(sim.log_path, str(sim.gt_path)))
                ate[name].append(res.score.ate_trans_rmse_m)
        ratios.append((ate["estimated"], ate["true"]))
        os.remove(sim.log_path)
    wall, cpu, ts = first
    steps = ", ".join(f"{k} {v:.1f}" for k, v in ts.items() if k != "total")
    row(rows, f"run time, {duration:.0f} s handheld log", "", f"{wall:.1f} s wall, {cpu:.1f} s CPU ({steps})",
        "<= 10 s", wall <= 10)
    mid = DRAWS_US.index(0)
    q = [e[mid] / t[mid] for e, t in ratios]
    each = ", ".join(f"{e[mid]:.3f}/{t[mid]:.3f} m" for e, t in ratios)
    row(rows, f"odom --calib, {duration:.0f} s handheld, no /tf_static", f"{seeds} logs, estimated vs true, one draw",
        f"ATE ratio median {np.median(q):.2f}x, worst {max(q):.2f}x ({each})", "<= 1.2x", max(q) <= 1.2)
    qm = [np.median(e) / np.median(t) for e, t in ratios]
    spread = ", ".join(f"{np.median(e):.3f} ({min(e):.3f}-{max(e):.3f}) / {np.median(t):.3f} ({min(t):.3f}-{max(t):.3f}) m"
                       for e, t in ratios)
    row(rows, f"odom --calib, {duration:.0f} s handheld, no /tf_static", f"{seeds} logs, median of {len(DRAWS_US)} draws "
        "(offset -2..+2 us)", f"ATE ratio median {np.median(qm):.2f}x, worst {max(qm):.2f}x ({spread})", "<= 1.2x",
        max(qm) <= 1.2)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--quick", action="store_true", help="offsets 5 and 50 ms, 20 s logs, a 20 min Allan log")
    ap.add_argument("--allan-hours", type=float, default=None)
    ap.add_argument("--only", choices=("e2e", "handheld", "tilted", "drive", "wheels", "allan"), action="append",
                    help="run only these parts (repeat)")
    args = ap.parse_args()
    offsets = (5, 50) if args.quick else OFFSETS_MS
    hand_s = 20.0 if args.quick else 30.0
    hours = args.allan_hours if args.allan_hours is not None else (1 / 3 if args.quick else 2.0)
    rows: list = []
    t_all = time.perf_counter()
    with tempfile.TemporaryDirectory(prefix="bench_calibrate_") as tmp:
        root = Path(tmp)
        parts = {
            "e2e": lambda: bench_end_to_end(root, 40.0, rows),
            "handheld": lambda: bench_handheld(root, offsets, hand_s, rows),
            "tilted": lambda: bench_handheld(root, offsets, hand_s, rows, tilt=3.0),
            "drive": lambda: bench_drive(root, 1, 30.0 if args.quick else 60.0, rows),
            "wheels": lambda: bench_wheels(root, 2 if args.quick else 10, 30.0 if args.quick else 60.0, rows),
            "allan": lambda: bench_allan(root, hours, rows),
        }
        for name, part in parts.items():
            if not args.only or name in args.only:
                part()
    head = ("quantity", "runs", "error (median / worst)", "goal", "met")
    widths = [max(len(str(r[i])) for r in rows + [head]) for i in range(5)]
    print("  ".join(h.ljust(w) for h, w in zip(head, widths)))
    print("  ".join("-" * w for w in widths))
    for r in rows:
        print("  ".join(str(c).ljust(w) for c, w in zip(r, widths)))
    print(f"\n(logs without /tf_static; load average {os.getloadavg()[0]:.1f} on {os.cpu_count()} cores; "
          f"benchmark wall time {time.perf_counter() - t_all:.0f} s)")


if __name__ == "__main__":
    main()
