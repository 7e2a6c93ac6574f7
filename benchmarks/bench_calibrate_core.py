#!/usr/bin/env python3
"""Accuracy and speed of the calibration estimators (lio_cli.core.calibration) against simulated truth.

Inputs are what `lio calibrate` will read from a log, made by lio's simulator pieces without writing one: a
LiDAR-only odometry trajectory (the LiDAR's true poses at 10 Hz in the frame of its first scan, with white
noise of 1.5 cm and 0.1 deg per axis per pose), raw IMU arrays (200 Hz, the simulator's noise, biases, random
walks and clock offset) and wheel odometry arrays (scale errors and a slip episode). The estimators run in
the order the command will use: IMU at rest -> time offset -> rotation -> lever arm (refining the rotation)
-> wheel scales; Allan on a 2 h static IMU log. Each row is the issue's target; error columns give the median
and the worst over the seeds.

  python benchmarks/bench_calibrate_core.py                   # 5 seeds
  python benchmarks/bench_calibrate_core.py --seeds 10 --allan-hours 2
"""

from __future__ import annotations

import argparse
import time

import numpy as np

from lio_cli.core.calibration import (estimate_allan, estimate_imu_static, estimate_lever_arm, estimate_rotation,
                                      estimate_time_offset, estimate_wheel_scales)
from lio_cli.geometry import make_pose, so3_exp, so3_log
from lio_cli.simulation.calibration_inputs import calibration_inputs
from lio_cli.simulation.motion import Path2D, Progress, Trajectory
from lio_cli.simulation.sensors import ImuSpec, WheelSpec, synthesize_imu

NS = 1_000_000_000
OFFSETS_MS = (5, 10, 20, 50, 100)


def chain(d) -> dict:
    """The command's order on one log; returns the results and the wall time of each step."""
    imu, out, t = d.imu, {}, {}
    t0 = time.perf_counter()
    out["static"] = estimate_imu_static(imu.stamps_ns, imu.gyro_radps, imu.accel_mps2)
    t["static"] = time.perf_counter() - t0
    t0 = time.perf_counter()
    out["offset"] = estimate_time_offset(d.lidar_stamps_ns, d.T_world_lidar, imu.stamps_ns, imu.gyro_radps,
                                         gyro_bias_radps=out["static"].gyro_bias_radps)
    t["offset"] = time.perf_counter() - t0
    off = out["offset"].imu_time_offset_s
    t0 = time.perf_counter()
    out["rotation"] = estimate_rotation(d.lidar_stamps_ns, d.T_world_lidar, imu.stamps_ns, imu.gyro_radps,
                                        imu_time_offset_s=off, gyro_bias_radps=out["static"].gyro_bias_radps)
    t["rotation"] = time.perf_counter() - t0
    t0 = time.perf_counter()
    rot = out["rotation"]
    out["lever"] = estimate_lever_arm(d.lidar_stamps_ns, d.T_world_lidar, imu.stamps_ns, imu.gyro_radps,
                                      imu.accel_mps2, R_lidar_imu=rot.R_lidar_imu,
                                      rotation_covariance_rad2=rot.covariance_rad2, imu_time_offset_s=off,
                                      gyro_bias_radps=rot.gyro_bias_radps)
    t["lever"] = time.perf_counter() - t0
    out["times"] = t
    return out


def rot_err_deg(R: np.ndarray, d) -> np.ndarray:
    return np.degrees(so3_log(R @ d.T_lidar_imu[:3, :3].T))


def med_worst(x) -> str:
    x = np.abs(np.asarray(x, float))
    return f"{np.median(x):.3g} / {x.max():.3g}"


def row(rows: list, quantity: str, truth: str, estimate: str, error: str, goal: str, ok: bool | None = None) -> None:
    rows.append((quantity, truth, estimate, error, goal, "" if ok is None else ("yes" if ok else "NO")))


def bench_time_offsets(seeds: int, rows: list) -> None:
    errs = []
    for i, ms in enumerate(OFFSETS_MS):
        for sign in (1, -1):
            for s in range(max(1, seeds // 5)):
                off = sign * ms * 1e-3
                d = calibration_inputs("handheld", 40.0, seed=100 + 10 * i + s + (sign > 0), imu_time_offset_s=off)
                r = chain(d)["offset"]
                errs.append((r.imu_time_offset_s - off) * 1e3)
    e = np.abs(errs)
    row(rows, "time offset, handheld 40 s", "+-5..100 ms", f"{len(e)} runs", f"median {np.median(e):.3f} ms, "
        f"worst {e.max():.3f} ms", "<= 0.5 / 1 ms", np.median(e) <= 0.5 and e.max() <= 1.0)


def bench_handheld(seeds: int, rows: list, pos_noise_m: float = 0.015) -> list[float]:
    rot, rot_ref, lev, lev_z, times = [], [], [], [], []
    for s in range(seeds):
        d = calibration_inputs("handheld", 40.0, seed=200 + s, imu_time_offset_s=0.02, pos_noise_m=pos_noise_m)
        t0 = time.perf_counter()
        out = chain(d)
        times.append(time.perf_counter() - t0)
        rot.append(np.linalg.norm(rot_err_deg(out["rotation"].R_lidar_imu, d)))
        rot_ref.append(np.linalg.norm(rot_err_deg(out["lever"].R_lidar_imu, d)))
        e = out["lever"].t_lidar_imu_m - d.T_lidar_imu[:3, 3]
        lev.append(100 * np.linalg.norm(e))
        lev_z.append(100 * abs(e[2]))
    truth = np.degrees(np.linalg.norm(so3_log(d.T_lidar_imu[:3, :3])))
    if pos_noise_m != 0.015:
        row(rows, f"translation, handheld, {100 * pos_noise_m:g} cm trajectory noise", "", f"{seeds} seeds",
            f"{med_worst(lev)} cm (z {med_worst(lev_z)})", "<= 2 cm", max(lev) <= 2.0)
        return times
    row(rows, "rotation, handheld (gyro hand-eye)", f"{truth:.1f} deg", f"{seeds} seeds", f"{med_worst(rot)} deg",
        "<= 0.2 deg", max(rot) <= 0.2)
    row(rows, "rotation, handheld (+ accelerations)", "", "", f"{med_worst(rot_ref)} deg", "<= 0.2 deg", max(rot_ref) <= 0.2)
    row(rows, "translation, handheld", f"{100 * np.linalg.norm(d.T_lidar_imu[:3, 3]):.1f} cm", f"{seeds} seeds",
        f"{med_worst(lev)} cm (z {med_worst(lev_z)})", "<= 2 cm", max(lev) <= 2.0)
    return times


def bench_drive(seeds: int, rows: list) -> None:
    gyro_obs, gyro_z, ref = [], [], []
    for s in range(seeds):
        d = calibration_inputs("drive", 60.0, seed=300 + s, imu_time_offset_s=-0.01)
        out = chain(d)
        e = rot_err_deg(out["rotation"].R_lidar_imu, d)
        obs = out["rotation"].observable
        gyro_obs.append(np.abs(e[obs]).max())
        gyro_z.append(abs(e[2]))
        ref.append(np.abs(rot_err_deg(out["lever"].R_lidar_imu, d)).max())
    row(rows, "rotation, driving 60 s (gyro, observable axes)", "roll/pitch/yaw", f"{seeds} seeds",
        f"{med_worst(gyro_obs)} deg (yaw {med_worst(gyro_z)})", "<= 0.5 deg", max(gyro_obs) <= 0.5)
    row(rows, "rotation, driving 60 s (+ accelerations, all axes)", "", "", f"{med_worst(ref)} deg", "<= 0.5 deg",
        max(ref) <= 0.5)


def bench_wheels(seeds: int, rows: list) -> None:
    for name, dur, r0, b0 in (("planar", 60.0, 0.08, 0.42), ("drive", 60.0, 0.32, 1.6)):
        ev, ew = [], []
        for s in range(seeds):
            rng = np.random.default_rng(400 + s)
            sl, sr, bs = 1 + rng.normal(0, 0.01), 1 + rng.normal(0, 0.01), 1 + rng.normal(0, 0.03)
            spec = WheelSpec(radius_m=r0, baseline_m=b0, radius_scale_left=sl, radius_scale_right=sr, baseline_scale=bs,
                             slip_start_s=0.4 * dur, slip_duration_s=3.0, slip_left=0.25, slip_right=0.10)
            d = calibration_inputs(name, dur, seed=400 + s, wheel_spec=spec)
            r = estimate_wheel_scales(d.wheel.stamps_ns, d.wheel.linear_mps, d.wheel.angular_radps, d.lidar_stamps_ns,
                                      d.T_world_lidar, T_base_traj=d.T_base_lidar, radius_m=r0, baseline_m=b0)
            s_v = 0.5 * (sl + sr)
            ev.append(100 * (r.speed_scale / s_v - 1))
            ew.append(100 * (r.yaw_rate_scale / (s_v / bs) - 1))
        row(rows, f"wheel speed scale, {name} {dur:.0f} s + slip", "1 +- 1%", f"{seeds} seeds", f"{med_worst(ev)} %",
            "<= 0.3 %", max(np.abs(ev)) <= 0.3)
        row(rows, f"wheel yaw-rate scale, {name} {dur:.0f} s + slip", "1 +- 3%", "", f"{med_worst(ew)} %", "<= 0.3 %",
            max(np.abs(ew)) <= 0.3)


def bench_allan(hours: float, seeds: int, rows: list) -> None:
    spec = ImuSpec()
    still = Trajectory(Path2D(np.array([(0.0, 0.0), (1.0, 0.0), (1.0, 1.0)])), Progress(0.0))
    err = {k: [] for k in ("gn", "gk", "an", "ak", "gk_axes", "ak_axes", "gs", "as")}
    walls = []
    for s in range(seeds):
        imu = synthesize_imu(still, make_pose(so3_exp([0.1, -0.2, 0.7])), spec, 0, int(hours * 3600) * NS, 0,
                             np.random.default_rng(500 + s))
        t0 = time.perf_counter()
        r = estimate_allan(imu.stamps_ns, imu.gyro_radps, imu.accel_mps2)
        walls.append(time.perf_counter() - t0)
        for key, fit, n_true, k_true in (("g", r.gyro, spec.gyro_noise_density, spec.gyro_bias_walk),
                                         ("a", r.accel, spec.accel_noise_density, spec.accel_bias_walk)):
            err[key + "n"].append(100 * (fit.noise_density_mean / n_true - 1))
            err[key + "k"].append(100 * (fit.random_walk_mean / k_true - 1))
            err[key + "k_axes"].extend(100 * (fit.random_walk / k_true - 1))
            err[key + "s"].append(np.nanmean(fit.random_walk_slope))
        del imu
    for key, name, n_true, k_true in (("g", "gyro", spec.gyro_noise_density, spec.gyro_bias_walk),
                                      ("a", "accel", spec.accel_noise_density, spec.accel_bias_walk)):
        en, ek = np.abs(err[key + "n"]), np.abs(err[key + "k"])
        row(rows, f"Allan {name} white noise, {hours:g} h", f"{n_true:.3g}", f"{seeds} logs", f"{med_worst(en)} %",
            "within 10 %", en.max() <= 10)
        row(rows, f"Allan {name} random walk, {hours:g} h (axes mean)", f"{k_true:.3g}", f"{seeds} logs",
            f"{med_worst(ek)} % (single axes {med_worst(err[key + 'k_axes'])} %; slope {np.mean(err[key + 's']):+.2f})",
            "within 10 %", ek.max() <= 10)
    row(rows, f"Allan run time, {hours:g} h at 200 Hz, 6 axes", "", f"{np.median(walls):.1f} s", "", "seconds")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--seeds", type=int, default=5)
    ap.add_argument("--allan-hours", type=float, default=2.0)
    ap.add_argument("--allan-logs", type=int, default=3, help="static logs simulated for Allan (10 s and 0.7 GB each)")
    args = ap.parse_args()
    rows: list = []
    t_all = time.perf_counter()
    bench_time_offsets(args.seeds, rows)
    times = bench_handheld(args.seeds, rows)
    bench_handheld(args.seeds, rows, pos_noise_m=0.01)
    bench_drive(args.seeds, rows)
    bench_wheels(args.seeds, rows)
    bench_allan(args.allan_hours, args.allan_logs, rows)
    d = calibration_inputs("handheld", 40.0, seed=600)
    out = chain(d)
    dp = calibration_inputs("planar", 40.0, seed=600)  # the handheld log has no wheels: time them on 40 s planar
    t0 = time.perf_counter()
    estimate_wheel_scales(dp.wheel.stamps_ns, dp.wheel.linear_mps, dp.wheel.angular_radps, dp.lidar_stamps_ns,
                          dp.T_world_lidar, T_base_traj=dp.T_base_lidar)
    wheel_s = time.perf_counter() - t0
    total = sum(out["times"].values()) + wheel_s
    steps = ", ".join(f"{k} {v:.2f}" for k, v in out["times"].items())
    row(rows, "run time, 40 s log (static, offset, rotation, lever, wheel)", "", f"{total:.2f} s",
        f"({steps}, wheel {wheel_s:.2f}; median of {len(times)} handheld chains {np.median(times):.2f} s)", "<= 10 s",
        total <= 10.0)
    head = ("quantity", "truth", "estimate", "error (median / worst)", "goal", "met")
    widths = [max(len(str(r[i])) for r in rows + [head]) for i in range(6)]
    print("  ".join(h.ljust(w) for h, w in zip(head, widths)))
    print("  ".join("-" * w for w in widths))
    for r in rows:
        print("  ".join(str(c).ljust(w) for c, w in zip(r, widths)))
    print(f"\n(trajectory noise 1.5 cm / 0.1 deg per pose, white; IMU 200 Hz with the simulator's default noise; "
          f"benchmark wall time {time.perf_counter() - t_all:.0f} s)")


if __name__ == "__main__":
    main()
