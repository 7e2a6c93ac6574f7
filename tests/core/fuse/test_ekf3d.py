"""The 3D error-state EKF: hand-checkable steps, simulated logs against ground truth, and bad input."""

from __future__ import annotations

import time

import numpy as np

from lio_cli.core.fuse import FuseInputs, FuseOptions, ImuSeries, NoiseOptions, PoseSeries, WheelSeries, fuse
from lio_cli.evaluation import EvalOptions, Trajectory, evaluate
from lio_cli.geometry import interpolate_poses, make_pose, quat_xyzw_to_rot, rot_to_quat_xyzw, so3_exp, yaw_of
from lio_cli.simulation.fusion_case import START_NS, OdomNoise, simulate_case

MS = 1_000_000
EXACT = 1e-9
ODOM_ATE_RATIO = 0.85  # fused ATE at 100 Hz truth stamps vs the odometry's own (measured 0.64)
RPE_RATIO = 0.5  # fused RPE over 0.05 s vs linearly interpolated odometry (the target; measured ~0.41)
WHEEL_ATE_RATIO = 0.25  # IMU + wheels vs wheel dead reckoning (target 0.5, measured 0.15)


def ate(case, stamps, poses) -> float:
    ref = Trajectory(case.truth_stamps_ns, case.truth_poses, "gt")
    return evaluate(ref, Trajectory(stamps, poses, "est"), EvalOptions(align="se3")).stats["ape"]["trans"]["rmse"]


def rpe_005(case, stamps, poses) -> float:
    ref = Trajectory(case.truth_stamps_ns, case.truth_poses, "gt")
    opts = EvalOptions(align="se3", delta=0.05, delta_unit="s", max_diff_ns=MS)
    return evaluate(ref, Trajectory(stamps, poses, "est"), opts).stats["rpe"]["trans"]["rmse"]


def test_constant_velocity_odometry_update_gain_by_hand():
    # no IMU: constant-velocity model; two odometry poses 0.1 s apart, the robot 0.1 m further along x
    dt, nz = 0.1, NoiseOptions()
    T1 = make_pose(t=np.array([0.1, 0.0, 0.0]))
    odom = PoseSeries(np.array([START_NS, START_NS + 100 * MS]), np.stack([np.eye(4), T1]))
    res = fuse(FuseInputs(odom=odom), FuseOptions(estimator="ekf", use={"odom": {"pose"}}))
    # first pose anchors the odometry frame; predict: P_xx = sv^2 dt^2 + q dt^3 / 3, P_xv = sv^2 dt
    sv2, q, r2 = nz.init_velocity_sigma_mps**2, nz.cv_accel_density**2, nz.odom_position_sigma_m**2
    p_xx, p_xv = sv2 * dt**2 + q * dt**3 / 3.0, sv2 * dt
    k_x, k_v = p_xx / (p_xx + r2), p_xv / (p_xx + r2)
    np.testing.assert_array_equal(res.stamps_ns, odom.stamps_ns)
    np.testing.assert_allclose(res.poses[1, :3, 3], [k_x * 0.1, 0.0, 0.0], rtol=1e-8, atol=EXACT)
    np.testing.assert_allclose(res.velocities_mps[1], [k_v * 0.1, 0.0, 0.0], rtol=1e-8, atol=EXACT)
    np.testing.assert_allclose(res.covariances[1, 0, 0], p_xx - k_x * p_xx, rtol=1e-6)
    assert res.reports["odom"].updates == 1 and res.reports["odom"].notes == {"anchor": 1}


def test_pure_rotation_integrates_the_gyro_exactly():
    n, w = 401, 0.5
    st = START_NS + np.arange(n, dtype=np.int64) * 5 * MS
    imu = ImuSeries(st, np.tile([0.0, 0.0, w], (n, 1)), np.tile([0.0, 0.0, 9.81], (n, 1)), np.eye(4))
    res = fuse(FuseInputs(imu=imu), FuseOptions(estimator="ekf"))
    t_s = (res.stamps_ns - st[0]) * 1e-9
    np.testing.assert_allclose(np.unwrap(yaw_of(res.poses[:, :3, :3])), w * t_s, atol=EXACT)
    np.testing.assert_allclose(res.poses[:, :3, 3], 0.0, atol=EXACT)
    assert "moving start" in res.info["start"]  # a steady turn is not taken for a gyro bias


def test_odometry_plus_imu_beats_odometry_absolute_and_between_scans():
    case = simulate_case("handheld", 12.0, seed=5, wheels=False, odom=OdomNoise())
    od = case.inputs.odom
    res = fuse(case.inputs, FuseOptions(estimator="ekf"))  # filter at every IMU sample (200 Hz)
    assert len(res) == len(case.inputs.imu)
    q = case.truth_stamps_ns[(case.truth_stamps_ns >= od.stamps_ns[0]) & (case.truth_stamps_ns <= od.stamps_ns[-1])]
    interp = interpolate_poses(od.stamps_ns, od.poses, q)
    assert ate(case, res.stamps_ns, res.poses) < ODOM_ATE_RATIO * ate(case, od.stamps_ns, od.poses)
    assert rpe_005(case, res.stamps_ns, res.poses) < RPE_RATIO * rpe_005(case, q, interp)
    assert res.reports["odom"].updates == len(od) - 1 and not res.reports["odom"].rejected


def test_imu_and_wheels_beat_wheel_dead_reckoning():
    case = simulate_case("planar", 40.0, seed=1)
    res = fuse(case.inputs, FuseOptions(estimator="ekf", rate_hz=50.0))
    dr = ate(case, case.inputs.wheel.stamps_ns, case.wheel_dead_reckoning)
    assert ate(case, res.stamps_ns, res.poses) < WHEEL_ATE_RATIO * dr
    assert res.info["use"] == {"imu": ["accel", "gyro"], "wheel": ["speed"]}
    np.testing.assert_allclose(res.poses[0, :3, 3], 0.0)  # starts at the origin


def test_covariance_symmetrised_now_and_then_gives_the_same_trajectory(monkeypatch):
    # P = (P + P^T)/2 only every SYMMETRIZE_EVERY steps while P stays inside the filter: rounding-level change
    from lio_cli.core.fuse import ekf3d

    assert ekf3d.SYMMETRIZE_EVERY > 1
    case = simulate_case("planar", 20.0, seed=2)
    sparse = fuse(case.inputs, FuseOptions(estimator="ekf", rate_hz=50.0))
    monkeypatch.setattr(ekf3d, "SYMMETRIZE_EVERY", 1)
    every = fuse(case.inputs, FuseOptions(estimator="ekf", rate_hz=50.0))
    assert len(sparse.poses) == len(every.poses) > 900
    np.testing.assert_allclose(sparse.poses, every.poses, rtol=0, atol=1e-9)
    monkeypatch.undo()
    cov = fuse(case.inputs, FuseOptions(estimator="ekf", rate_hz=50.0, want_covariance=True)).covariances
    assert np.array_equal(cov, np.transpose(cov, (0, 2, 1)))  # a recorded P is symmetrised at every step


def test_relative_odometry_with_clean_data_tracks_truth():
    clean = OdomNoise(position_sigma_m=1e-4, rotation_sigma_rad=1e-5, drift_yaw_rw=0.0, drift_position_rw=0.0)
    case = simulate_case("handheld", 8.0, seed=2, wheels=False, odom=clean, imu_noise_scale=0.1)
    res = fuse(case.inputs, FuseOptions(estimator="ekf", use={"imu": {"gyro", "accel"}, "odom": {"delta"}}))
    assert ate(case, res.stamps_ns, res.poses) < 0.005
    assert res.reports["odom"].updates == len(case.inputs.odom) - 1


def test_bad_messages_are_counted_and_do_not_change_the_result():
    case = simulate_case("planar", 6.0, seed=4)
    imu, wheel = case.inputs.imu, case.inputs.wheel
    clean = fuse(case.inputs, FuseOptions(estimator="ekf", rate_hz=20.0))
    n = len(wheel)
    # wheel: 5 duplicated messages arriving late, 4 rows of NaN, variance 0 and -1 (ROS "unknown")
    dup = np.arange(10, 15)
    st = np.concatenate([wheel.stamps_ns, wheel.stamps_ns[dup], START_NS + np.array([1, 2, 3, 4]) * MS])
    vel = np.vstack([wheel.velocity_mps, wheel.velocity_mps[dup] + 5.0, np.full((4, 3), np.nan)])
    yaw = np.concatenate([wheel.yaw_rate_radps, wheel.yaw_rate_radps[dup], np.full(4, np.nan)])
    var = np.zeros((n + 9, 3))
    var[::2, 0] = -1.0
    # IMU: 20 neighbouring pairs swapped in arrival order
    order = np.arange(len(imu))
    for k in range(100, 1100, 50):
        order[[k, k + 1]] = order[[k + 1, k]]
    bad = FuseInputs(imu=ImuSeries(imu.stamps_ns[order], imu.gyro_radps[order], imu.accel_mps2[order], imu.T_base_imu),
                     wheel=WheelSeries(st, vel, yaw, var, None))
    res = fuse(bad, FuseOptions(estimator="ekf", rate_hz=20.0))
    np.testing.assert_allclose(res.poses, clean.poses, atol=EXACT)
    assert res.reports["imu"].notes == {"reordered": 20}
    assert res.reports["wheel"].rejected == {"nan": 4, "duplicate_stamp": 5}
    assert res.reports["wheel"].notes == {"reordered": 5, "default_noise": n}  # the late duplicates


def test_long_gap_costs_one_step():
    seg = np.arange(401, dtype=np.int64) * 5 * MS
    st = np.concatenate([START_NS + seg, START_NS + 3600 * 10**9 + seg])  # two 2 s stretches an hour apart
    n = len(st)
    imu = ImuSeries(st, np.zeros((n, 3)), np.tile([0.0, 0.0, 9.81], (n, 1)), np.eye(4))
    t0 = time.perf_counter()
    res = fuse(FuseInputs(imu=imu), FuseOptions(estimator="ekf", rate_hz=100.0))
    assert time.perf_counter() - t0 < 1.0  # (would be an hour of 200 Hz steps if integrated)
    assert len(res) == 2 * 201
    assert res.reports["imu"].notes == {"gaps": 1}
    assert res.info["motion_gaps"] == 1
    before, after = res.covariances[200, 0, 0], res.covariances[201, 0, 0]
    assert after > 1e3 * before  # an hour without data leaves the position unknown


def test_odometry_glitch_is_rejected_as_outlier():
    case = simulate_case("handheld", 8.0, seed=3, wheels=False, odom=OdomNoise())
    ref = fuse(case.inputs, FuseOptions(estimator="ekf", rate_hz=50.0))
    poses = case.inputs.odom.poses.copy()
    poses[40, :3, 3] += [3.0, 0.0, 0.0]  # a registration failure
    case.inputs.odom = PoseSeries(case.inputs.odom.stamps_ns, poses)
    res = fuse(case.inputs, FuseOptions(estimator="ekf", rate_hz=50.0))
    assert res.reports["odom"].rejected == {"outlier": 1}
    assert np.abs(res.poses[:, :3, 3] - ref.poses[:, :3, 3]).max() < 0.01


def test_imu_orientation_defines_the_world_heading():
    case = simulate_case("planar", 20.0, seed=2, wheels=True)
    imu = case.inputs.imu
    R_wb = interpolate_poses(case.truth_stamps_ns, case.truth_poses, imu.stamps_ns)[:, :3, :3]
    q = rot_to_quat_xyzw(R_wb @ imu.T_base_imu[:3, :3])
    cov = np.tile(np.eye(3) * np.radians(1.0) ** 2, (len(imu), 1, 1))
    gyro = imu.gyro_radps.copy()
    gyro[400:] += imu.T_base_imu[:3, :3].T @ [0.0, 0.0, 0.02]  # a bias change after the standing start
    case.inputs.imu = ImuSeries(imu.stamps_ns, gyro, imu.accel_mps2, imu.T_base_imu, q, None, cov)
    res = fuse(case.inputs, FuseOptions(estimator="ekf", rate_hz=10.0))
    assert res.info["world_yaw_from"] == "imu_orientation"
    truth = interpolate_poses(case.truth_stamps_ns, case.truth_poses, res.stamps_ns)
    dyaw = np.angle(np.exp(1j * (yaw_of(res.poses[:, :3, :3]) - yaw_of(truth[:, :3, :3]))))
    assert np.abs(dyaw).max() < np.radians(1.0)  # without the orientation updates: 20 deg
    np.testing.assert_allclose(quat_xyzw_to_rot(q[0]) @ imu.T_base_imu[:3, :3].T, R_wb[0], atol=1e-12)


def test_gps_gives_the_heading_and_bounds_the_drift():
    case = simulate_case("planar", 60.0, seed=1, gps_sigma_m=0.5)
    res = fuse(case.inputs, FuseOptions(estimator="ekf", rate_hz=10.0, smooth=True))
    assert res.info["world_yaw_from"] == "gps"
    truth = interpolate_poses(case.truth_stamps_ns, case.truth_poses, res.stamps_ns)
    err = res.poses[:, :3, 3] - (truth[:, :3, 3] - truth[0, :3, 3])  # world = ENU shifted to the start
    # 0.5 m fixes at 5 Hz: the smoothed path (start included) is far better than one fix (measured 0.14 m)
    assert np.sqrt(np.mean(np.sum(err[:, :2] ** 2, axis=1))) < 0.25
    dyaw = np.angle(np.exp(1j * (yaw_of(res.poses[0, :3, :3]) - yaw_of(truth[0, :3, :3]))))
    assert abs(dyaw) < np.radians(3.0)
    by_kind = res.reports["gps"].by_kind  # each fix: a horizontal and a vertical update
    assert by_kind["gps"]["updates"] == by_kind["gps_vertical"]["updates"] == len(case.inputs.gps)
    assert res.reports["gps"].notes == {"anchor": 1}


def test_wheel_twist_without_imu_uses_the_constant_velocity_model():
    case = simulate_case("planar", 20.0, seed=1, wheel_errors=False)
    res = fuse(FuseInputs(wheel=case.inputs.wheel), FuseOptions(estimator="ekf"))
    assert res.info["model"] == "cv" and res.info["use"] == {"wheel": ["speed", "yaw_rate"]}
    assert ate(case, res.stamps_ns, res.poses) < 0.05  # error-free wheels: close to the truth


def test_lever_arm_of_a_spinning_imu_is_removed():
    # the base spins in place at 2 rad/s; the IMU sits 0.54 m off its axis (rotated 90 deg): it feels a
    # centripetal 2.2 m/s^2 that must not move the base
    w = 2.0
    T_bi = make_pose(so3_exp(np.array([0.0, 0.0, np.pi / 2])), np.array([0.5, 0.2, 0.0]))
    R_bi, r = T_bi[:3, :3], T_bi[:3, 3]
    w_b = np.array([0.0, 0.0, w])
    f_b = np.cross(w_b, np.cross(w_b, r)) + np.array([0.0, 0.0, 9.81])
    n = 401
    st = START_NS + np.arange(n, dtype=np.int64) * 5 * MS
    imu = ImuSeries(st, np.tile(R_bi.T @ w_b, (n, 1)), np.tile(R_bi.T @ f_b, (n, 1)), T_bi)
    res = fuse(FuseInputs(imu=imu), FuseOptions(estimator="ekf"))
    np.testing.assert_allclose(res.poses[:, :3, 3], 0.0, atol=1e-6)
    np.testing.assert_allclose(np.unwrap(yaw_of(res.poses[:, :3, :3])), w * (res.stamps_ns - st[0]) * 1e-9, atol=EXACT)


def test_imu_mounting_rotation_is_applied_on_a_real_path():
    case = simulate_case("corridor", 10.0, seed=0, wheels=True, wheel_errors=False, imu_noise_scale=0.0)
    T = case.inputs.imu.T_base_imu
    assert not np.allclose(T[:3, :3], np.eye(3)) and np.any(T[:3, 3])
    res = fuse(case.inputs, FuseOptions(estimator="ekf", rate_hz=50.0))
    assert ate(case, res.stamps_ns, res.poses) < 0.02


def test_a_robot_seen_again_an_hour_later_has_not_travelled_an_hour_at_its_last_speed():
    from lio_cli.core.fuse.state3d import GAP_TAU_S

    seg = np.arange(101, dtype=np.int64) * 20 * MS  # 2 s of wheel twist at 1 m/s, straight, twice
    st = np.concatenate([START_NS + seg, START_NS + 3600 * 10**9 + seg])
    n = len(st)
    wheel = WheelSeries(st, np.tile([1.0, np.nan, np.nan], (n, 1)), np.zeros(n))
    for estimator in ("ekf", "planar", "complementary"):  # (every estimator bridges gaps the same way)
        res = fuse(FuseInputs(wheel=wheel), FuseOptions(estimator=estimator))
        before, after = res.poses[100, :3, 3], res.poses[101, :3, 3]
        assert res.info["motion_gaps"] == 1
        assert np.linalg.norm(after - before) <= 1.0 * GAP_TAU_S + 0.05  # not 3600 m
        np.testing.assert_allclose(res.poses[100, 0, 3], 2.0, atol=0.05)  # before the gap: the wheels


def test_gap_search_runs_once_per_covered_stretch_not_once_per_step(monkeypatch):
    """ardrone has ~300 covered stretches: the coverage-gap search (a bisection) runs only where a step
    leaves the stretch it was in, and the gaps are crossed as before (one hold step each)."""
    from lio_cli.core.fuse import ekf3d

    seg = np.arange(201, dtype=np.int64) * 5 * MS  # 1 s at 200 Hz, then 3 s without data, ten times
    st = np.concatenate([START_NS + k * 4 * 10**9 + seg for k in range(10)])
    n = len(st)
    imu = ImuSeries(st, np.zeros((n, 3)), np.tile([0.0, 0.0, 9.81], (n, 1)), np.eye(4))
    calls, gaps = [], []
    search = ekf3d.in_coverage_gap
    monkeypatch.setattr(ekf3d, "in_coverage_gap", lambda *a: calls.append(a[2]) or gaps.append(search(*a)) or gaps[-1])
    res = fuse(FuseInputs(imu=imu), FuseOptions(estimator="ekf"))
    assert res.info["motion_gaps"] == 9 and sum(gaps) == 9
    assert len(calls) <= 2 * 10  # at each stretch's start and end, not at each of the ~2000 steps


def test_outputs_at_imu_stamps_cost_no_loop_round_of_their_own(monkeypatch):
    """Outputs at every IMU stamp (the default) ride on the IMU sample's event: the filter loop goes round
    once per IMU sample, not twice, and still gives one pose per sample."""
    from lio_cli.core.fuse import ekf3d, kalman

    seg = np.arange(201, dtype=np.int64) * 5 * MS
    n = len(seg)
    imu = ImuSeries(START_NS + seg, np.zeros((n, 3)), np.tile([0.0, 0.0, 9.81], (n, 1)), np.eye(4))
    rounds = []
    fold = ekf3d.folded_outputs
    monkeypatch.setattr(ekf3d, "folded_outputs", lambda prep: [rounds.append(len(c[0])) or c for c in [fold(prep)]][0])
    marks = []
    mark = kalman.KnotLog.mark_output
    monkeypatch.setattr(kalman.KnotLog, "mark_output", lambda self: marks.append(1) or mark(self))
    res = fuse(FuseInputs(imu=imu), FuseOptions(estimator="ekf"))
    assert rounds == [n] and len(marks) == n and len(res) == n
