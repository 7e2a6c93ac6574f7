#!/usr/bin/env python3
"""Accuracy and speed of the estimation core of `lio fuse` (lio_cli.core.fuse), before the CLI exists.

(1) LiDAR odometry + IMU (simulated: true poses at 10 Hz with 2 cm / 0.2 deg white noise and a random-walk
    drift in every increment; a 200 Hz IMU with biases and noise): the 200 Hz fused trajectory's ATE at
    the 100 Hz ground-truth stamps against the odometry's ATE at its own stamps (target: fused <= odom),
    and RPE over 0.05 s against the odometry interpolated linearly to the ground-truth stamps (target:
    fused <= 0.5x).
(2) IMU + wheels only (planar robot, corridor): ATE against plain wheel dead reckoning (target <= 0.5x).
    The wheels carry calibration errors (radius +-1 %, baseline +5 %) and one 2 s slip episode.
(3) Real logs: robot_localization's regression test on jackal.bag (test_ekf_localization_node_bag2:
    wheel velocities and yaw rate, IMU orientation, rates and accelerations; expected end point
    (1.0206, 3.4292, 0.7419) within 0.138 m), and groovy.bag / ardrone.bag must run without error.
    Speed is the log's duration over the CPU time of fuse() (target >= 100x for IMU + wheel fusion).

ATE = APE translation RMSE after SE(3) alignment; RPE = translation RMSE over 0.05 s pairs; both from
lio_cli.evaluation (evo's definitions). CPU time (time.process_time) is reported since other processes
share the machine; wall time beside it.

    python benchmarks/bench_fuse_core.py                # all sections, 60 s simulations
    python benchmarks/bench_fuse_core.py --duration 30 --sections 1 3
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np

from lio_cli.core.fuse import FuseInputs, FuseOptions, ImuSeries, NoiseOptions, PoseSeries, WheelSeries, fuse
from lio_cli.evaluation import EvalOptions, evaluate
from lio_cli.evaluation.association import Trajectory
from lio_cli.geometry import interpolate_poses, pose_from_xyz_quat
from lio_cli.simulation.fusion_case import OdomNoise, simulate_case

ROOT = Path(__file__).resolve().parents[1]
# ../shared/real_logs relative to the project root (a worktree sits one level deeper)
REAL_LOGS_CANDIDATES = (ROOT.parent / "shared" / "real_logs", ROOT.parent.parent / "shared" / "real_logs")
RL_END = np.array([1.0206, 3.4292, 0.7419])
RL_TOL_M = 0.1383
MS = 1_000_000


def ate(gt: Trajectory, stamps, poses) -> float:
    return evaluate(gt, Trajectory(stamps, poses, "est"), EvalOptions(align="se3")).stats["ape"]["trans"]["rmse"]


def rpe(gt: Trajectory, stamps, poses, delta_s: float = 0.05) -> float:
    opts = EvalOptions(align="se3", delta=delta_s, delta_unit="s", max_diff_ns=MS)
    return evaluate(gt, Trajectory(stamps, poses, "est"), opts).stats["rpe"]["trans"]["rmse"]


def timed(fn):
    c0, w0 = time.process_time(), time.perf_counter()
    out = fn()
    return out, time.process_time() - c0, time.perf_counter() - w0


def section_odom(duration: float, seed: int) -> bool:
    print(f"\n(1) LiDAR odometry (10 Hz, 2 cm / 0.2 deg noise + drift) + IMU (200 Hz), {duration:.0f} s; "
          "fused output at every IMU sample")
    print(f"{'scenario':<9} {'trajectory':<30} {'ATE m':>8} {'RPE.05 m':>9} {'ATE/odom':>9} {'RPE/interp':>11} "
          f"{'cpu s':>6} {'x rt':>6}")
    ok = True
    for scen in ("handheld", "drive", "corridor"):
        case = simulate_case(scen, duration, seed=seed, wheels=False, odom=OdomNoise())
        gt = Trajectory(case.truth_stamps_ns, case.truth_poses, "gt")
        od = case.inputs.odom
        q = case.truth_stamps_ns[(case.truth_stamps_ns >= od.stamps_ns[0]) & (case.truth_stamps_ns <= od.stamps_ns[-1])]
        odom_ate = ate(gt, od.stamps_ns, od.poses)
        interp_rpe = rpe(gt, q, interpolate_poses(od.stamps_ns, od.poses, q))
        print(f"{scen:<9} {'odometry at its stamps':<30} {odom_ate:>8.4f} {'':>9}")
        print(f"{'':<9} {'odometry interpolated (100 Hz)':<30} {ate(gt, q, interpolate_poses(od.stamps_ns, od.poses, q)):>8.4f} "
              f"{interp_rpe:>9.4f}")
        delta = {"imu": {"gyro", "accel"}, "odom": {"delta"}}
        runs = [("EKF filter", FuseOptions()), ("EKF + RTS smoother", FuseOptions(smooth=True)),
                ("EKF odom delta, filter", FuseOptions(use=delta)),
                ("EKF odom delta + smoother", FuseOptions(smooth=True, use=delta)),
                ("complementary a=0.3", FuseOptions(estimator="complementary", alpha_odom=0.3))]
        for name, opts in runs:
            res, cpu, _ = timed(lambda o=opts: fuse(case.inputs, o))
            a, r = ate(gt, res.stamps_ns, res.poses), rpe(gt, res.stamps_ns, res.poses)
            good = a <= odom_ate and r <= 0.5 * interp_rpe
            if name == "EKF + RTS smoother":
                ok &= good
            print(f"{'':<9} {name:<30} {a:>8.4f} {r:>9.4f} {a / odom_ate:>9.2f} {r / interp_rpe:>11.2f} {cpu:>6.2f} "
                  f"{duration / cpu:>6.0f}{'' if good else '  (misses a target)'}")
    print("targets: ATE/odom <= 1, RPE/interp <= 0.5 (checked on the EKF + RTS smoother row)")
    return ok


def section_wheels(duration: float, seed: int) -> bool:
    print(f"\n(2) IMU (200 Hz) + wheels (50 Hz, calibration errors and a slip), no LiDAR, {duration:.0f} s; output 50 Hz")
    print(f"{'scenario':<9} {'trajectory':<26} {'ATE m':>8} {'ATE/DR':>7} {'cpu s':>6} {'x rt':>6}")
    ok = True
    for scen in ("planar", "corridor"):
        case = simulate_case(scen, duration, seed=seed)
        gt = Trajectory(case.truth_stamps_ns, case.truth_poses, "gt")
        dr = ate(gt, case.inputs.wheel.stamps_ns, case.wheel_dead_reckoning)
        print(f"{scen:<9} {'wheel dead reckoning':<26} {dr:>8.3f}")
        for name, opts in (("EKF 3D", FuseOptions(rate_hz=50.0)), ("EKF 3D + smoother", FuseOptions(rate_hz=50.0, smooth=True)),
                           ("planar EKF", FuseOptions(estimator="planar", rate_hz=50.0)),
                           ("complementary", FuseOptions(estimator="complementary", rate_hz=50.0))):
            res, cpu, _ = timed(lambda o=opts: fuse(case.inputs, o))
            a = ate(gt, res.stamps_ns, res.poses)
            ok &= a <= 0.5 * dr
            print(f"{'':<9} {name:<26} {a:>8.3f} {a / dr:>7.2f} {cpu:>6.2f} {duration / cpu:>6.0f}")
    print("target: ATE/DR <= 0.5 (every estimator)")
    return ok


# -- real logs ---------------------------------------------------------------------------------------
def _stamp(msg) -> int:
    return int(msg.header.stamp.sec) * 1_000_000_000 + int(msg.header.stamp.nanosec)


def read_log(path: Path, imu_topic: str | None, odom_topic: str | None) -> tuple[ImuSeries | None, list]:
    from lio_cli.io.logs.reader import open_log

    imu, odo = [], []
    with open_log(path) as reader:
        for topic, _, _, m in reader.messages([t for t in (imu_topic, odom_topic) if t]):
            if topic == imu_topic:
                o, c = m.orientation, np.asarray(m.orientation_covariance, float).reshape(3, 3)
                imu.append((_stamp(m), (m.angular_velocity.x, m.angular_velocity.y, m.angular_velocity.z),
                            (m.linear_acceleration.x, m.linear_acceleration.y, m.linear_acceleration.z),
                            (o.x, o.y, o.z, o.w), c))
            else:
                odo.append(m)
    series = None
    if imu:
        series = ImuSeries(np.array([a[0] for a in imu], np.int64), np.array([a[1] for a in imu]),
                           np.array([a[2] for a in imu]), np.eye(4), np.array([a[3] for a in imu]), None,
                           np.array([a[4] for a in imu]))
    return series, odo


def wheel_from_odometry(msgs: list, components=(0, 1, 2), yaw_rate: bool = True) -> WheelSeries:
    """nav_msgs/Odometry twist as the wheel source: the chosen linear components, NaN for the others."""
    st = np.array([_stamp(m) for m in msgs], np.int64)
    lin = np.array([(m.twist.twist.linear.x, m.twist.twist.linear.y, m.twist.twist.linear.z) for m in msgs])
    cov = np.array([np.asarray(m.twist.covariance, float).reshape(6, 6) for m in msgs])
    vel = np.full_like(lin, np.nan)
    vel[:, list(components)] = lin[:, list(components)]
    yaw = np.array([m.twist.twist.angular.z for m in msgs]) if yaw_rate else np.full(len(msgs), np.nan)
    return WheelSeries(st, vel, yaw, np.stack([cov[:, 0, 0], cov[:, 1, 1], cov[:, 2, 2]], axis=1), cov[:, 5, 5])


def poses_from_odometry(msgs: list) -> PoseSeries:
    st = np.array([_stamp(m) for m in msgs], np.int64)
    p = np.array([(m.pose.pose.position.x, m.pose.pose.position.y, m.pose.pose.position.z) for m in msgs])
    q = np.array([(m.pose.pose.orientation.x, m.pose.pose.orientation.y, m.pose.pose.orientation.z,
                   m.pose.pose.orientation.w) for m in msgs])
    good = np.linalg.norm(q, axis=1) > 0.5
    T = np.zeros((len(msgs), 4, 4))  # a zero quaternion stays a zero "rotation": the core rejects it
    T[:, :3, 3], T[:, 3, 3] = p, 1.0
    T[good] = pose_from_xyz_quat(p[good], q[good])
    return PoseSeries(st, T)


def section_real(real_logs: Path, rough_accel_density: float) -> bool:
    print("\n(3) real logs")
    jackal = real_logs / "jackal_imu_wheel" / "jackal.bag"
    if not jackal.exists():
        print(f"  {real_logs} not found: skipped (the real logs live in the workplace only)")
        return True
    (imu, odo), read_cpu, _ = timed(lambda: read_log(jackal, "/imu/data", "/jackal_velocity_controller/odom"))
    inputs = FuseInputs(imu=imu, wheel=wheel_from_odometry(odo))
    duration = (imu.stamps_ns[-1] - imu.stamps_ns[0]) * 1e-9
    use = {"imu": {"gyro", "accel", "orientation"}, "wheel": {"velocity", "yaw_rate"}}  # robot_localization's bag2 selection
    print(f"jackal.bag ({duration:.1f} s, {len(imu)} IMU + {len(odo)} wheel messages; reading took {read_cpu:.2f} s cpu)")
    print(f"  robot_localization expects the end at ({RL_END[0]}, {RL_END[1]}, {RL_END[2]}) within {RL_TOL_M} m")
    print(f"  {'run':<44} {'end x, y, z (m)':<26} {'diff m':>7} {'xy m':>6} {'cpu s':>6} {'x rt':>6} {'wall x rt':>9}")
    ok = True
    runs = [(f"EKF, rough-terrain accel noise {rough_accel_density:g}", FuseOptions(use=use, noise=NoiseOptions(accel_noise_density=rough_accel_density))),
            ("EKF + smoother, same noise", FuseOptions(use=use, smooth=True, noise=NoiseOptions(accel_noise_density=rough_accel_density))),
            (f"EKF, default noise ({NoiseOptions().accel_noise_density:g})", FuseOptions(use=use)),
            ("planar EKF", FuseOptions(estimator="planar", use=use)),
            ("complementary", FuseOptions(estimator="complementary", use=use))]
    for k, (name, opts) in enumerate(runs):
        res, cpu, wall = timed(lambda o=opts: fuse(inputs, o))
        end = res.poses[-1, :3, 3]
        d, dxy = float(np.linalg.norm(end - RL_END)), float(np.linalg.norm(end[:2] - RL_END[:2]))
        if k == 0:
            ok &= d <= RL_TOL_M and duration / cpu >= 100.0
            rep = res.reports
        print(f"  {name:<44} {end[0]:>7.3f} {end[1]:>7.3f} {end[2]:>7.3f}   {d:>7.3f} {dxy:>6.3f} {cpu:>6.2f} {duration / cpu:>6.0f} "
              f"{duration / wall:>9.0f}{'' if d <= RL_TOL_M else '  (outside the tolerance)'}")
    print("  counters of the first run: " + "; ".join(f"{s}: {v.to_dict()}" for s, v in rep.items()))

    groovy = real_logs / "groovy_imu_wheel_stereo" / "groovy.bag"
    imu, wheel_msgs = read_log(groovy, "/xsens/imu_data", "/wheel_odometry")
    _, stereo = read_log(groovy, None, "/stereo_odometer/odometry")
    bogus, _ = read_log(groovy, "/my_odometry2imu/imu_data", None)
    gcases = [
        ("groovy: xsens IMU + wheel twist", FuseInputs(imu=imu, wheel=wheel_from_odometry(wheel_msgs)), FuseOptions(rate_hz=50.0)),
        ("groovy: xsens IMU + stereo odometry (pose)", FuseInputs(imu=imu, odom=poses_from_odometry(stereo)),
         FuseOptions(rate_hz=50.0, use={"imu": {"gyro", "accel", "orientation"}, "odom": {"pose"}})),
        ("groovy: all-zero IMU + wheel twist", FuseInputs(imu=bogus, wheel=wheel_from_odometry(wheel_msgs)), FuseOptions(rate_hz=50.0)),
    ]
    ardrone = real_logs / "ardrone_twist_only" / "ardrone.bag"
    imu_a, odo_a = read_log(ardrone, "/ardrone/imu", "/ardrone/odometry/raw")
    # the driver fills only the planar twist (vx, vy); its pose quaternion is (0,0,0,0)
    gcases.append(("ardrone: IMU + twist-only odometry", FuseInputs(imu=imu_a, wheel=wheel_from_odometry(odo_a, (0, 1), False)),
                   FuseOptions(use={"imu": {"gyro", "accel", "orientation"}, "wheel": {"velocity"}})))
    gcases.append(("ardrone: same, pose quaternions as odometry", FuseInputs(imu=imu_a, odom=poses_from_odometry(odo_a)),
                   FuseOptions(use={"imu": {"gyro", "accel", "orientation"}, "odom": {"pose"}})))
    print(f"\n  {'log and sources':<44} {'result':<46} {'cpu s':>6} {'x rt':>6}")
    from lio_cli.errors import LioError

    for name, inp, opts in gcases:
        span = max(s.stamps_ns[-1] - s.stamps_ns[0] for s in inp.present().values()) * 1e-9
        try:
            res, cpu, _ = timed(lambda i=inp, o=opts: fuse(i, o))
            e = res.poses[-1, :3, 3]
            text = f"{len(res)} poses, end ({e[0]:.1f}, {e[1]:.1f}, {e[2]:.1f}) m"
            print(f"  {name:<44} {text:<46} {cpu:>6.2f} {span / cpu:>6.0f}")
            print(f"    {'; '.join(f'{s}: upd {v.updates} rej {v.rejected} notes {v.notes}' for s, v in res.reports.items())}")
        except LioError as err:  # a clean one-line refusal is the expected outcome for some inputs
            print(f"  {name:<44} refused: {err}")
    return ok


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--duration", type=float, default=60.0, help="simulated seconds per scenario")
    ap.add_argument("--seed", type=int, default=1)
    ap.add_argument("--sections", type=int, nargs="*", default=[1, 2, 3])
    ap.add_argument("--real-logs", type=Path, default=next((p for p in REAL_LOGS_CANDIDATES if p.exists()),
                                                            REAL_LOGS_CANDIDATES[0]))
    ap.add_argument("--rough-accel-density", type=float, default=0.5,
                    help="accelerometer noise density for the Jackal (a skid-steer robot shaking over grass)")
    args = ap.parse_args()
    results = {}
    if 1 in args.sections:
        results["odometry + IMU"] = section_odom(args.duration, args.seed)
    if 2 in args.sections:
        results["IMU + wheels"] = section_wheels(args.duration, args.seed)
    if 3 in args.sections:
        results["real logs"] = section_real(args.real_logs, args.rough_accel_density)
    print("\ntargets: " + ", ".join(f"{k}: {'met' if v else 'MISSED'}" for k, v in results.items()))
    return 0


if __name__ == "__main__":
    sys.exit(main())
