"""The lecture's planar EKF (x, y, theta, v, omega, b_omega)."""

from __future__ import annotations

import numpy as np

from lio_cli.core.fuse import FuseInputs, FuseOptions, WheelSeries, fuse
from lio_cli.core.fuse.planar_model import delta_residual, predict, wrap
from lio_cli.evaluation import EvalOptions, Trajectory, evaluate
from lio_cli.geometry import make_pose, so3_exp, yaw_of
from lio_cli.simulation.fusion_case import START_NS, OdomNoise, simulate_case

MS = 1_000_000
LECTURE_TOL_M = 1e-6
WHEEL_ATE_RATIO = 0.25  # gyro + wheels vs wheel dead reckoning (target 0.5, measured ~0.1)


def ate(case, res) -> float:
    ref = Trajectory(case.truth_stamps_ns, case.truth_poses, "gt")
    return evaluate(ref, Trajectory(res.stamps_ns, res.poses, "est"), EvalOptions(align="se3")).stats["ape"]["trans"]["rmse"]


def test_exact_wheel_data_reproduces_the_lecture_integration():
    # lecture: x_k+1 = x_k + v_k cos(theta_k) dt, y likewise, theta_k+1 = theta_k + omega_k dt; the heading
    # taken at the step's middle, theta_k + omega_k dt / 2 (second order on an arc)
    n, dt = 60, 0.02
    rng = np.random.default_rng(0)
    v = 1.0 + 0.3 * np.sin(np.arange(n) * 0.1)
    w = 0.5 * np.cos(np.arange(n) * 0.07) + 0.01 * rng.normal(size=n)
    st = START_NS + np.arange(n, dtype=np.int64) * 20 * MS
    wheel = WheelSeries(st, np.column_stack([v, np.full(n, np.nan), np.full(n, np.nan)]), w,
                        np.full((n, 3), 1e-12), np.full(n, 1e-12))
    res = fuse(FuseInputs(wheel=wheel), FuseOptions(estimator="planar", gate_probability=0.0))
    x = np.zeros((n, 3))
    for k in range(n - 1):
        mid = x[k, 2] + 0.5 * w[k] * dt
        x[k + 1] = x[k] + [v[k] * np.cos(mid) * dt, v[k] * np.sin(mid) * dt, w[k] * dt]
    np.testing.assert_allclose(res.poses[:, :2, 3], x[:, :2], atol=LECTURE_TOL_M)
    np.testing.assert_allclose(np.unwrap(yaw_of(res.poses[:, :3, :3])), x[:, 2], atol=LECTURE_TOL_M)


def test_predict_jacobian_and_delta_jacobian_match_numerical():
    eps = 1e-7
    x = np.array([1.0, -2.0, 0.7, 1.3, -0.4, 0.01, 0.5, -1.5, 0.2])
    F = predict(x.copy(), 0.05, 9)
    D = make_pose(so3_exp(np.array([0.0, 0.0, 0.3])), np.array([0.4, 0.1, 0.0]))
    r0, H = delta_residual(x, D)
    Fn, Hn = np.zeros((9, 9)), np.zeros((3, 9))
    base = x.copy()
    predict(base, 0.05, 9)
    for k in range(9):
        xp = x.copy()
        xp[k] += eps
        Hn[:, k] = -(delta_residual(xp, D)[0] - r0) / eps
        predict(xp, 0.05, 9)
        Fn[:, k] = (xp - base) / eps
    np.testing.assert_allclose(Fn, F, atol=1e-6)
    np.testing.assert_allclose(Hn, H, atol=1e-6)


def test_wrap_keeps_angles_in_minus_pi_pi():
    np.testing.assert_allclose([wrap(a) for a in (0.1, np.pi + 0.1, -np.pi - 0.1, 7 * np.pi)],
                               [0.1, -np.pi + 0.1, np.pi - 0.1, -np.pi], atol=1e-12)


def test_gyro_and_wheels_beat_dead_reckoning():
    case = simulate_case("planar", 40.0, seed=1)
    res = fuse(case.inputs, FuseOptions(estimator="planar", rate_hz=50.0))
    dr = Trajectory(case.inputs.wheel.stamps_ns, case.wheel_dead_reckoning, "dr")
    ref = Trajectory(case.truth_stamps_ns, case.truth_poses, "gt")
    dr_ate = evaluate(ref, dr, EvalOptions(align="se3")).stats["ape"]["trans"]["rmse"]
    assert ate(case, res) < WHEEL_ATE_RATIO * dr_ate
    assert res.info["use"] == {"imu": ["gyro"], "wheel": ["speed"]}  # no accelerometer model
    assert res.reports["imu"].updates == len(case.inputs.imu)
    assert np.all(res.poses[:, 2, 3] == 0.0) and np.all(res.covariances[:, 2, 2] == 0.0)


def test_relative_odometry_gyro_and_smoother_on_a_planar_robot():
    case = simulate_case("planar", 20.0, seed=3, wheels=False, odom=OdomNoise())
    od = case.inputs.odom
    ref = Trajectory(case.truth_stamps_ns, case.truth_poses, "gt")
    odom_ate = evaluate(ref, Trajectory(od.stamps_ns, od.poses, "odom"), EvalOptions(align="se3")).stats["ape"]["trans"]["rmse"]
    use = {"imu": {"gyro"}, "odom": {"delta"}}
    filt = fuse(case.inputs, FuseOptions(estimator="planar", use=use, rate_hz=20.0))
    smooth = fuse(case.inputs, FuseOptions(estimator="planar", use=use, smooth=True, rate_hz=20.0))
    assert filt.reports["odom"].updates == len(od) - 1
    assert ate(case, filt) < 0.8 * odom_ate  # measured 0.67
    assert ate(case, smooth) < 0.5 * odom_ate  # measured 0.31


def test_gap_prediction_jacobian_and_bounded_travel():
    from lio_cli.core.fuse.planar_model import predict_gap
    from lio_cli.core.fuse.state3d import GAP_TAU_S

    x = np.array([0.0, 0.0, 0.3, 1.5, 0.2, 0.0])
    F = predict_gap(x.copy(), 3600.0, 6)
    y = x.copy()
    predict_gap(y, 3600.0, 6)
    assert np.hypot(y[0], y[1]) <= 1.5 * GAP_TAU_S + 1e-9 and abs(y[3]) < 1e-12
    eps, Fn = 1e-7, np.zeros((6, 6))
    for k in range(6):
        xp = x.copy()
        xp[k] += eps
        predict_gap(xp, 0.5, 6)
        base = x.copy()
        predict_gap(base, 0.5, 6)
        Fn[:, k] = (xp - base) / eps
    np.testing.assert_allclose(Fn, predict_gap(x.copy(), 0.5, 6), atol=1e-6)
    assert F.shape == (6, 6)
