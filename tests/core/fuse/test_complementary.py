"""The lecture's complementary filter: one step by the formula, and on simulated logs."""

from __future__ import annotations

import numpy as np

from lio_cli.core.fuse import FuseInputs, FuseOptions, ImuSeries, PoseSeries, fuse
from lio_cli.core.fuse.complementary import blend_rotation
from lio_cli.evaluation import EvalOptions, Trajectory, evaluate
from lio_cli.geometry import interpolate_poses, make_pose, so3_exp, so3_log, yaw_of
from lio_cli.simulation.fusion_case import START_NS, OdomNoise, simulate_case

MS = 1_000_000
EXACT = 1e-9


def test_one_step_is_the_lecture_formula():
    # theta_fused = alpha * theta_scan + (1 - alpha) * (theta_prev + omega_gyro * dt)
    alpha, w, dt = 0.98, 0.5, 0.1
    n = 21  # IMU at 200 Hz over 0.1 s, turning at 0.5 rad/s (a moving start: no bias taken)
    st = START_NS + np.arange(n, dtype=np.int64) * 5 * MS
    imu = ImuSeries(st, np.tile([0.0, 0.0, w], (n, 1)), np.tile([0.0, 0.0, 9.81], (n, 1)), np.eye(4))
    # two scan poses; the odometry frame's heading at the first is 0.3 rad (the anchor maps it to 0)
    T0 = make_pose(so3_exp(np.array([0.0, 0.0, 0.3])))
    T1 = make_pose(so3_exp(np.array([0.0, 0.0, 0.3 + 0.06])))
    odom = PoseSeries(np.array([st[0], st[-1]]), np.stack([T0, T1]))
    res = fuse(FuseInputs(imu=imu, odom=odom),
               FuseOptions(estimator="complementary", alpha_odom=alpha, use={"imu": {"gyro"}, "odom": {"pose"}}))
    theta_prev, theta_scan = 0.0, 0.06
    expected = alpha * theta_scan + (1 - alpha) * (theta_prev + w * dt)
    np.testing.assert_allclose(yaw_of(res.poses[-1, :3, :3]), expected, atol=EXACT)
    np.testing.assert_allclose(yaw_of(res.poses[10, :3, :3]), w * 0.05, atol=EXACT)  # gyro only between scans
    assert res.covariances is None and res.reports["odom"].updates == 1


def test_blend_rotation_is_the_weighted_sum_about_one_axis():
    axis = np.array([1.0, 2.0, -0.5]) / np.linalg.norm([1.0, 2.0, -0.5])
    Ra, Rb = so3_exp(axis * 0.2), so3_exp(axis * 1.1)
    R = blend_rotation(Ra, Rb, 0.25)
    np.testing.assert_allclose(so3_log(R), axis * (0.25 * 1.1 + 0.75 * 0.2), atol=1e-12)


def test_odometry_and_imu_smooth_between_scans():
    case = simulate_case("handheld", 12.0, seed=5, wheels=False, odom=OdomNoise())
    od = case.inputs.odom
    ref = Trajectory(case.truth_stamps_ns, case.truth_poses, "gt")
    # scans with 2 cm noise: a lower alpha than the lecture's 0.98 lets the IMU carry more of the motion
    res = fuse(case.inputs, FuseOptions(estimator="complementary", alpha_odom=0.3))
    q = case.truth_stamps_ns[(case.truth_stamps_ns >= od.stamps_ns[0]) & (case.truth_stamps_ns <= od.stamps_ns[-1])]
    opts = EvalOptions(align="se3", delta=0.05, delta_unit="s", max_diff_ns=MS)
    rpe_interp = evaluate(ref, Trajectory(q, interpolate_poses(od.stamps_ns, od.poses, q), "i"), opts).stats["rpe"]["trans"]["rmse"]
    ev = evaluate(ref, Trajectory(res.stamps_ns, res.poses, "c"), opts)
    odom_ate = evaluate(ref, Trajectory(od.stamps_ns, od.poses, "o"), EvalOptions(align="se3")).stats["ape"]["trans"]["rmse"]
    assert ev.stats["rpe"]["trans"]["rmse"] < 0.5 * rpe_interp  # measured 0.37
    assert ev.stats["ape"]["trans"]["rmse"] < 0.8 * odom_ate  # measured 0.52


def test_gyro_and_wheels_beat_dead_reckoning():
    case = simulate_case("planar", 40.0, seed=1)
    ref = Trajectory(case.truth_stamps_ns, case.truth_poses, "gt")
    res = fuse(case.inputs, FuseOptions(estimator="complementary", rate_hz=50.0))
    a = evaluate(ref, Trajectory(res.stamps_ns, res.poses, "c"), EvalOptions(align="se3")).stats["ape"]["trans"]["rmse"]
    dr = evaluate(ref, Trajectory(case.inputs.wheel.stamps_ns, case.wheel_dead_reckoning, "dr"),
                  EvalOptions(align="se3")).stats["ape"]["trans"]["rmse"]
    assert a < 0.25 * dr
