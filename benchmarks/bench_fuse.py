#!/usr/bin/env python3
"""Accuracy and speed of `lio fuse`, end to end through the command (issue 13's targets).

(1) LiDAR odometry from `lio odom` + IMU (simulated logs, ground truth at 100 Hz): `lio fuse LOG --odom
    odom.tum --rate 200` (EKF filter, and with --smooth). Targets: the fused ATE at the ground truth's stamps
    <= lio odom's ATE at its scan stamps; RPE over 0.05 s (between scans) <= 0.5x that of the odometry
    interpolated linearly to the ground-truth stamps.
(2) IMU + wheels only (planar and corridor, wheel radius/baseline errors and a slip): fused ATE <= 0.5x plain
    wheel dead reckoning's (the wheel odometry's own poses, as the driver integrated them).
(3) Real logs: jackal.bag against robot_localization's regression test (test_ekf_localization_node_bag2:
    the EKF ends at (1.0206, 3.4292, 0.7419) within 0.138 m); groovy.bag (with an identity T_base_imu for the
    xsens frame, which the bag does not place) and ardrone.bag must run.
(4) Speed: log span over the CPU time of the job (read + decode + fuse, in process: `run_fuse`), target >= 100x
    for IMU + wheel fusion by the filter (`--no-smooth`; the defaults smooth since issue 27) on the real logs; the
    command's own process (interpreter start-up and imports included) beside it. CPU time since other processes share the machine; wall time too.

ATE = APE translation RMSE after SE(3) alignment; RPE = translation RMSE over 0.05 s pairs (1 ms matching);
both from lio_cli.evaluation (evo's definitions).

    python benchmarks/bench_fuse.py                       # every section, 30 s simulations
    python benchmarks/bench_fuse.py --sections 3 4
    python benchmarks/bench_fuse.py --duration 60 --scenarios drive
"""

from __future__ import annotations

import argparse
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from bytecode_cache import use_bytecode_cache

from lio_cli.cli.app import main as lio
from lio_cli.config.fuse import FuseConfig
from lio_cli.evaluation import EvalOptions, evaluate
from lio_cli.geometry import interpolate_poses
from lio_cli.io.sensors.sources import load_trajectory
from lio_cli.io.files.trajectory import read_tum
from lio_cli.jobs.fuse.job import FuseJob, run_fuse
from lio_cli.model.trajectory import Trajectory
from lio_cli.simulation.run import simulate

ROOT = Path(__file__).resolve().parents[1]
REAL_LOGS_CANDIDATES = (ROOT.parent / "shared" / "real_logs", Path("/work/shared/real_logs"))
RL_END = np.array([1.0206, 3.4292, 0.7419])
RL_TOL_M = 0.1383
MS = 1_000_000


def ate(gt: Trajectory, stamps, poses) -> float:
    return evaluate(gt, Trajectory(stamps, poses, "est"), EvalOptions(align="se3")).stats["ape"]["trans"]["rmse"]


def rpe(gt: Trajectory, stamps, poses, delta_s: float = 0.05) -> float:
    opts = EvalOptions(align="se3", delta=delta_s, delta_unit="s", max_diff_ns=MS)
    return evaluate(gt, Trajectory(stamps, poses, "est"), opts).stats["rpe"]["trans"]["rmse"]


def quiet_lio(*args) -> int:
    """Run a lio command in process with its stderr chatter silenced."""
    with open(os.devnull, "w") as null:
        old = sys.stderr
        sys.stderr = null
        try:
            return lio([str(a) for a in args])
        finally:
            sys.stderr = old


def gt_of(log: Path) -> Trajectory:
    t = load_trajectory(str(log.with_suffix(".gt.tum")))
    return Trajectory(t.stamps_ns, t.poses, "gt")


def section_odom(work: Path, scenarios: list[str], duration: float, seed: int) -> bool:
    print(f"\n(1) lio odom trajectory + IMU -> lio fuse --rate 200, {duration:.0f} s simulations")
    print(f"{'scenario':<9} {'trajectory':<34} {'ATE m':>8} {'RPE.05 m':>9} {'ATE/odom':>9} {'RPE/interp':>11}")
    ok = True
    for scen in scenarios:
        log = work / f"{scen}.bag"
        simulate(scen, log, duration_s=duration, seed=seed, force=True)
        gt = gt_of(log)
        odom = work / f"{scen}_odom.tum"
        if quiet_lio("odom", log, "-o", odom, "--force", "-q") != 0:
            print(f"{scen:<9} lio odom failed")
            ok = False
            continue
        ost, opo = read_tum(odom)
        q = gt.stamps_ns[(gt.stamps_ns >= ost[0]) & (gt.stamps_ns <= ost[-1])]
        interp = interpolate_poses(ost, opo, q)
        odom_ate, interp_rpe = ate(gt, ost, opo), rpe(gt, q, interp)
        print(f"{scen:<9} {'lio odom at its scan stamps':<34} {odom_ate:>8.4f}")
        print(f"{'':<9} {'lio odom interpolated to 100 Hz':<34} {ate(gt, q, interp):>8.4f} {interp_rpe:>9.4f}")
        for name, flags, wheels in (("fuse --rate 200 (EKF)", [], False), ("fuse --rate 200 --smooth", ["--smooth"], False),
                                    ("  + wheels, --smooth", ["--smooth"], True)):
            if wheels and scen == "handheld":  # a person walking: no wheels
                continue
            out = work / f"{scen}_fused.tum"
            use = ["--use", "imu:gyro,accel", "--use", "odom"] + (["--use", "wheel"] if wheels else [])
            code = quiet_lio("fuse", log, "--odom", odom, "--rate", 200, *use, *flags, "-o", out, "--force", "-q")
            if code != 0:
                print(f"{'':<9} {name:<34} failed (exit {code})")
                ok = False
                continue
            st, po = read_tum(out)
            a, r = ate(gt, st, po), rpe(gt, st, po)
            good = a <= odom_ate and r <= 0.5 * interp_rpe
            if name == "fuse --rate 200 --smooth":
                ok &= good
            print(f"{'':<9} {name:<34} {a:>8.4f} {r:>9.4f} {a / odom_ate:>9.2f} {r / interp_rpe:>11.2f}"
                  f"{'' if good else '  (misses a target)'}")
    print("targets: ATE/odom <= 1 and RPE/interp <= 0.5 (checked on the --smooth row)")
    return ok


def section_wheels(work: Path, duration: float, seed: int) -> bool:
    print(f"\n(2) IMU + wheels only (wheel calibration errors and a slip), {duration:.0f} s, output 50 Hz")
    print(f"{'scenario':<9} {'trajectory':<30} {'ATE m':>8} {'ATE/DR':>7}")
    ok = True
    for scen in ("planar", "corridor"):
        log = work / f"{scen}_w.bag"
        simulate(scen, log, duration_s=duration, seed=seed, force=True, columns=256 if scen == "corridor" else None)
        gt = gt_of(log)
        dr = load_trajectory(f"{log}:/wheel/odom")
        dr_ate = ate(gt, dr.stamps_ns, dr.poses)
        print(f"{scen:<9} {'wheel dead reckoning':<30} {dr_ate:>8.3f}")
        for name, flags in (("EKF 3D", []), ("EKF 3D --smooth", ["--smooth"]),
                            ("planar EKF", ["--estimator", "planar"]),
                            ("complementary", ["--estimator", "complementary", "--use", "imu:gyro", "--use", "wheel"])):
            out = work / f"{scen}_w.tum"
            code = quiet_lio("fuse", log, "--rate", 50, *flags, "-o", out, "--force", "-q")
            if code != 0:
                print(f"{'':<9} {name:<30} failed (exit {code})")
                ok = False
                continue
            st, po = read_tum(out)
            a = ate(gt, st, po)
            ok &= a <= 0.5 * dr_ate
            print(f"{'':<9} {name:<30} {a:>8.3f} {a / dr_ate:>7.2f}")
    print("target: ATE/DR <= 0.5 (every estimator)")
    return ok


def timed_job(log: Path, cfg: FuseConfig):
    c0, w0 = time.process_time(), time.perf_counter()
    run = run_fuse(FuseJob(log, cfg))
    return run, time.process_time() - c0, time.perf_counter() - w0


def process_cpu(args: list[str]) -> float:
    """CPU seconds of `lio ARGS` in its own process (start-up and imports included)."""
    proc = subprocess.Popen([str(Path(sys.executable).parent / "lio"), *args], stdout=subprocess.DEVNULL,
                            stderr=subprocess.DEVNULL)
    _, _, usage = os.wait4(proc.pid, 0)
    return usage.ru_utime + usage.ru_stime


def section_real(real: Path, work: Path) -> tuple[bool, bool]:
    print("\n(3) real logs, and (4) speed")
    jackal = real / "jackal_imu_wheel" / "jackal.bag"
    if not jackal.exists():
        print(f"  {real} not found: skipped (the real logs live in the workplace only)")
        return True, True
    calib = work / "identity_imu.yaml"
    calib.write_text("T_base_imu: [[1, 0, 0, 0], [0, 1, 0, 0], [0, 0, 1, 0], [0, 0, 0, 1]]\n")
    rl = {"imu": ["accel", "gyro", "orientation"], "wheel": ["velocity", "yaw_rate"]}  # robot_localization's bag2
    cases = [
        ("jackal: lio fuse defaults", jackal, FuseConfig(), []),
        ("jackal: robot_localization's sensors", jackal, FuseConfig(use=rl), ["--use", "imu", "--use", "wheel:velocity,yaw_rate"]),
        ("jackal: same, --accel-noise 0.5", jackal, FuseConfig(use=rl, noise={"accel_noise_density": 0.5}), []),
        ("jackal: defaults --smooth", jackal, FuseConfig(smooth=True), []),
        ("jackal: planar EKF", jackal, FuseConfig(estimator="planar"), []),
        ("jackal: complementary", jackal, FuseConfig(estimator="complementary"), []),
        ("groovy: xsens IMU + wheels", real / "groovy_imu_wheel_stereo" / "groovy.bag",
         FuseConfig(calibration={"T_base_imu": np.eye(4).tolist()}), ["--calib", calib]),
        ("ardrone: IMU + twist-only odometry", real / "ardrone_twist_only" / "ardrone.bag", FuseConfig(), []),
        ("jackal: --no-smooth", jackal, FuseConfig(smooth=False), ["--no-smooth"]),
        ("groovy: --no-smooth", real / "groovy_imu_wheel_stereo" / "groovy.bag",
         FuseConfig(smooth=False, calibration={"T_base_imu": np.eye(4).tolist()}), ["--calib", calib, "--no-smooth"]),
        ("ardrone: --no-smooth", real / "ardrone_twist_only" / "ardrone.bag", FuseConfig(smooth=False), ["--no-smooth"]),
    ]
    speed_rows = ("jackal: --no-smooth", "groovy: --no-smooth", "ardrone: --no-smooth")  # the target is the filter's
    print(f"  robot_localization expects jackal to end at ({RL_END[0]}, {RL_END[1]}, {RL_END[2]}) within {RL_TOL_M} m")
    print(f"  {'run':<38} {'end x, y, z (m)':<24} {'diff m':>7} {'read s':>7} {'fuse s':>7} {'cpu s':>6} "
          f"{'x rt':>6} {'wall x rt':>9} {'process x rt':>12}")
    ok_acc, ok_speed = True, True
    for name, log, cfg, flags in cases:
        run, cpu, wall = timed_job(log, cfg)
        span = run.metrics["log_span_s"]
        end = run.trajectory.positions[-1]
        t = run.metrics["time_s"]
        diff = ""
        if log == jackal:
            d = float(np.linalg.norm(end - RL_END))
            diff = f"{d:7.3f}"
            if name == "jackal: lio fuse defaults":
                ok_acc &= d <= RL_TOL_M
        proc = ""
        if name in speed_rows:
            ok_speed &= span / cpu >= 100.0
            pc = process_cpu(["fuse", str(log), "-o", str(work / "speed.tum"), "--force", "-q", *map(str, flags)])
            proc = f"{span / pc:>12.0f}"
        print(f"  {name:<38} {end[0]:>7.2f} {end[1]:>7.2f} {end[2]:>7.2f}  {diff:>7} {t['read']:>7.2f} "
              f"{t['fuse']:>7.2f} {cpu:>6.2f} {span / cpu:>6.0f} {span / wall:>9.0f} {proc}")
    print("  read/fuse: wall seconds of each stage; x rt: log span / CPU time of the job (target >= 100 on the "
          "--no-smooth rows: the filter; the defaults smooth); process: the whole `lio fuse` process, start-up included")
    return ok_acc, ok_speed


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--duration", type=float, default=30.0, help="simulated seconds per scenario")
    ap.add_argument("--seed", type=int, default=1)
    ap.add_argument("--scenarios", nargs="*", default=["handheld", "drive", "corridor"])
    ap.add_argument("--sections", type=int, nargs="*", default=[1, 2, 3])
    ap.add_argument("--real-logs", type=Path, default=next((p for p in REAL_LOGS_CANDIDATES if p.exists()),
                                                            REAL_LOGS_CANDIDATES[0]))
    args = ap.parse_args()
    use_bytecode_cache()
    results = {}
    with tempfile.TemporaryDirectory(prefix="bench_fuse_") as tmp:
        work = Path(tmp)
        if 1 in args.sections:
            results["odometry + IMU"] = section_odom(work, args.scenarios, args.duration, args.seed)
        if 2 in args.sections:
            results["IMU + wheels"] = section_wheels(work, args.duration, args.seed)
        if 3 in args.sections or 4 in args.sections:
            results["jackal end point"], results["speed >= 100x"] = section_real(args.real_logs, work)
    print("\ntargets: " + ", ".join(f"{k}: {'met' if v else 'MISSED'}" for k, v in results.items()))
    return 0


if __name__ == "__main__":
    sys.exit(main())
