"""Physics of `lio simulate`: exact kinematics, IMU that integrates back to the truth, wheel odometry,
motion skew that true-motion deskew removes, ray casting, and paths that never enter an obstacle."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial import cKDTree

from lio_cli.geometry import inv_pose, so3_exp, so3_log, transform_points
from lio_cli.simulation import SCENARIOS, build_scenario
from lio_cli.simulation.motion import Path2D, Progress, Sines, Trajectory
from lio_cli.simulation.sensors import (
    GRAVITY_MPS2,
    ImuSpec,
    LidarSpec,
    WheelSpec,
    spin_scan,
    synthesize_imu,
    wheel_odometry,
)
from lio_cli.simulation.world import World, footprint_clearance, raycast

NS = 1_000_000_000
POS_TOL_M = 0.01  # the bar: 1 cm after 10 s
ROT_TOL_DEG = 0.1
DERIV_RTOL = 1e-5
RANGE_NOISE_M = 0.015


def _integrate_imu(stamps_ns, gyro, accel, T0, v0):
    """Strapdown integration of IMU samples (linear between samples, coning-corrected rotation, Simpson)."""
    R, p, v = T0[:3, :3].copy(), T0[:3, 3].copy(), np.asarray(v0, float).copy()
    g = GRAVITY_MPS2
    for k in range(len(stamps_ns) - 1):
        dt = (stamps_ns[k + 1] - stamps_ns[k]) * 1e-9
        w0, w1, f0, f1 = gyro[k], gyro[k + 1], accel[k], accel[k + 1]
        R1 = R @ so3_exp((w0 + w1) / 2 * dt + np.cross(w0, w1) * dt * dt / 12)
        Rm = R @ so3_exp((3 * w0 + w1) / 8 * dt + np.cross(w0, w1) * dt * dt / 32)
        a0, am, a1 = R @ f0 + g, Rm @ ((f0 + f1) / 2) + g, R1 @ f1 + g
        p = p + v * dt + dt * dt / 6 * (a0 + 2 * am)
        v = v + dt / 6 * (a0 + 4 * am + a1)
        R = R1
    T = np.eye(4)
    T[:3, :3], T[:3, 3] = R, p
    return T


def _rot_err_deg(A, B):
    return float(np.degrees(np.linalg.norm(so3_log(A[:3, :3].T @ B[:3, :3]))))


@pytest.mark.parametrize("name", ["handheld", "drive"])
def test_noiseless_imu_integrates_to_ground_truth_after_10s(name):
    sc = build_scenario(name)
    imu = synthesize_imu(sc.trajectory, sc.T_base_imu, ImuSpec(), 0, 10 * NS, 0, rng=None)
    assert len(imu.stamps_ns) == 2001
    st = sc.trajectory.state(np.array([0.0, 10.0]))
    T_bi = sc.T_base_imu
    v_imu0 = st.velocity_mps[0] + st.R_world_base[0] @ np.cross(st.omega_base_radps[0], T_bi[:3, 3])
    T_wi = _integrate_imu(imu.stamps_ns, imu.gyro_radps, imu.accel_mps2, st.poses[0] @ T_bi, v_imu0)
    T_wb = T_wi @ inv_pose(T_bi)
    travelled = np.linalg.norm(st.position_m[1] - st.position_m[0])
    assert travelled > 5.0  # it really moved
    assert np.linalg.norm(T_wb[:3, 3] - st.position_m[1]) < POS_TOL_M
    assert _rot_err_deg(T_wb, st.poses[1]) < ROT_TOL_DEG


def test_handheld_sweeps_exceed_3_radps_and_starts_at_rest():
    sc = build_scenario("handheld")
    st = sc.trajectory.state(np.arange(0.0, 30.0, 0.005))
    assert np.abs(st.omega_base_radps[:, 2]).max() > 3.0
    speed = np.linalg.norm(st.velocity_mps, axis=1)
    rest = st.t_s < sc.trajectory.t_rest_s
    np.testing.assert_allclose(speed[rest], 0.0, atol=1e-12)
    np.testing.assert_allclose(st.omega_base_radps[rest], 0.0, atol=1e-12)
    assert 1.0 < speed[st.t_s > 5.0].mean() < 1.5


def test_accelerometer_at_rest_reads_gravity_up_in_imu_frame():
    sc = build_scenario("planar")  # IMU yawed 90 deg, level: +9.81 on its z
    imu = synthesize_imu(sc.trajectory, sc.T_base_imu, ImuSpec(), 0, NS // 2, 0, rng=None)
    np.testing.assert_allclose(imu.accel_mps2, np.tile([0.0, 0.0, 9.81], (len(imu.stamps_ns), 1)), atol=1e-9)
    np.testing.assert_allclose(imu.gyro_radps, 0.0, atol=1e-12)


def test_imu_bias_noise_and_time_offset():
    sc = build_scenario("handheld")
    spec = ImuSpec(accel_bias0_mps2=np.array([0.05, -0.02, 0.03]), gyro_bias0_radps=np.array([0.002, 0.0, -0.001]),
                   imu_time_offset_ns=-5_000_000)
    ideal = synthesize_imu(sc.trajectory, sc.T_base_imu, ImuSpec(imu_time_offset_ns=-5_000_000), 0, NS, 0, rng=None)
    noisy = synthesize_imu(sc.trajectory, sc.T_base_imu, spec, 0, NS, 0, rng=np.random.default_rng(3))
    # stamps on the IMU clock's regular grid; the samples belong to true time stamp + offset (at rest here)
    np.testing.assert_array_equal(noisy.stamps_ns, np.arange(0, NS + 1, 5_000_000))
    err = noisy.accel_mps2 - ideal.accel_mps2 - noisy.accel_bias_mps2
    expected_std = spec.accel_noise_density * np.sqrt(spec.rate_hz)
    np.testing.assert_allclose(err.std(axis=0), expected_std, rtol=0.2)
    np.testing.assert_allclose((noisy.gyro_radps - ideal.gyro_radps).mean(axis=0), spec.gyro_bias0_radps, atol=5e-4)
    np.testing.assert_allclose(noisy.accel_bias_mps2[0], spec.accel_bias0_mps2)


def test_imu_time_offset_shifts_the_signal():
    sc = build_scenario("handheld")
    offset_ns = 7_000_000
    a = synthesize_imu(sc.trajectory, sc.T_base_imu, ImuSpec(), 4 * NS, 5 * NS, 0, rng=None)
    b = synthesize_imu(sc.trajectory, sc.T_base_imu, ImuSpec(imu_time_offset_ns=-offset_ns), 4 * NS + offset_ns,
                       5 * NS + offset_ns, 0, rng=None)
    np.testing.assert_array_equal(b.stamps_ns - offset_ns, a.stamps_ns)
    np.testing.assert_allclose(b.gyro_radps, a.gyro_radps, atol=1e-12)


def test_trajectory_derivatives_match_finite_differences():
    sc = build_scenario("handheld")
    t, h = np.linspace(2.0, 20.0, 400), 1e-5
    st, sp, sm = (sc.trajectory.state(x) for x in (t, t + h, t - h))
    np.testing.assert_allclose(st.velocity_mps, (sp.position_m - sm.position_m) / (2 * h), atol=1e-6)
    np.testing.assert_allclose(st.accel_mps2, (sp.velocity_mps - sm.velocity_mps) / (2 * h), atol=1e-4)
    dR = (sp.R_world_base - sm.R_world_base) / (2 * h)
    W = np.einsum("nji,njk->nik", st.R_world_base, dR)
    omega_fd = np.stack([W[:, 2, 1], W[:, 0, 2], W[:, 1, 0]], axis=1)
    np.testing.assert_allclose(st.omega_base_radps, omega_fd, atol=1e-6)
    np.testing.assert_allclose(st.alpha_base_radps2, (sp.omega_base_radps - sm.omega_base_radps) / (2 * h), atol=1e-3)


def test_wheel_odometry_reproduces_planar_ground_truth_without_errors():
    sc = build_scenario("planar")
    odo = wheel_odometry(sc.trajectory, sc.wheels, 0, 10 * NS, 0)
    assert len(odo.stamps_ns) == 501
    T_gt = sc.trajectory.poses(odo.stamps_ns * 1e-9)
    T_rel = inv_pose(T_gt[0]) @ T_gt
    np.testing.assert_allclose(odo.poses_odom_base[:, :3, 3], T_rel[:, :3, 3], atol=1e-4)
    yaw_err = [_rot_err_deg(a, b) for a, b in zip(odo.poses_odom_base, T_rel)]
    assert max(yaw_err) < 1e-3
    v_true = np.linalg.norm(sc.trajectory.state(odo.stamps_ns * 1e-9).velocity_mps, axis=1)
    np.testing.assert_allclose(odo.linear_mps, v_true, atol=1e-9)


def test_wheel_errors_and_slip_make_odometry_drift_in_the_slip_window():
    sc = build_scenario("planar")
    ok = wheel_odometry(sc.trajectory, sc.wheels, 0, 10 * NS, 0)
    bad_spec = WheelSpec(radius_m=0.08, baseline_m=0.42, slip_start_s=5.0, slip_duration_s=1.0, slip_left=0.3)
    bad = wheel_odometry(sc.trajectory, bad_spec, 0, 10 * NS, 0)
    t = ok.stamps_ns * 1e-9
    inside = (t > 5.2) & (t < 5.8)
    np.testing.assert_allclose(bad.linear_mps[t < 4.9], ok.linear_mps[t < 4.9], atol=1e-12)
    assert np.all(bad.linear_mps[inside] > ok.linear_mps[inside] * 1.1)  # overestimated speed while slipping
    assert np.all(bad.angular_radps[inside] < ok.angular_radps[inside] - 0.1)  # left wheel spins: turns right
    scaled = wheel_odometry(sc.trajectory, WheelSpec(radius_m=0.08, baseline_m=0.42, radius_scale_left=1.02,
                                                     radius_scale_right=1.02), 0, 10 * NS, 0)
    np.testing.assert_allclose(scaled.linear_mps, ok.linear_mps / 1.02, rtol=1e-9)


def _deskew(points, stamps_ns, traj, T_bl, ref_ns):
    T_wl = traj.poses(stamps_ns * 1e-9) @ T_bl
    T_ref = traj.poses(np.array([ref_ns * 1e-9]))[0] @ T_bl
    return transform_points(inv_pose(T_ref) @ T_wl, points), T_ref


def test_true_motion_deskew_equals_a_standing_sensor_scan():
    sc = build_scenario("handheld")
    spec = LidarSpec(beams=16, columns=512, range_noise_m=RANGE_NOISE_M, dropout=0.0)
    start = int(6.3 * NS)  # walking with a fast sweep
    omega = sc.trajectory.state(np.array([6.35])).omega_base_radps[0]
    assert np.linalg.norm(omega) > 1.0
    raw = spin_scan(sc.world, sc.trajectory, sc.T_base_lidar, spec, start, 0, rng=np.random.default_rng(0))
    ref_ns = raw.end_ns
    deskewed, T_ref = _deskew(raw.points, raw.stamps_ns, sc.trajectory, sc.T_base_lidar, ref_ns)

    def range_residual(pts):
        rng_m = np.linalg.norm(pts, axis=1)
        dirs_w = (pts / rng_m[:, None]) @ T_ref[:3, :3].T
        seen, _ = raycast(sc.world, T_ref[:3, 3], dirs_w, spec.max_range_m)
        return np.abs(np.where(np.isfinite(seen), seen, 1e3) - rng_m)

    res_deskewed, res_raw = range_residual(deskewed), range_residual(raw.points)
    # Points lie on what the standing sensor sees, within range noise (a few land on occlusion edges).
    assert np.mean(res_deskewed < 4 * RANGE_NOISE_M) > 0.97
    assert np.mean(res_raw < 4 * RANGE_NOISE_M) < 0.8  # the raw scan really is skewed
    # And against an actual scan from a sensor frozen at the reference instant.
    static = spin_scan(sc.world, sc.trajectory, sc.T_base_lidar, LidarSpec(beams=16, columns=2048, range_noise_m=0.0,
                       dropout=0.0), start, 0, rng=None, frozen_ns=ref_ns)
    tree = cKDTree(static.points)
    d_deskewed, _ = tree.query(deskewed)
    d_raw, _ = tree.query(raw.points)
    assert np.median(d_deskewed) < 0.5 * np.median(d_raw)


def test_scan_points_are_in_the_sensor_frame_at_their_own_instant():
    sc = build_scenario("handheld")
    spec = LidarSpec(beams=16, columns=128, dropout=0.0)
    scan = spin_scan(sc.world, sc.trajectory, sc.T_base_lidar, spec, 5 * NS, 0, rng=None)
    T_wl = sc.trajectory.poses(scan.stamps_ns * 1e-9) @ sc.T_base_lidar
    p_w = np.einsum("nij,nj->ni", T_wl[:, :3, :3], scan.points) + T_wl[:, :3, 3]
    # re-cast each point's ray from its own pose: the hit is the point itself
    dirs = p_w - T_wl[:, :3, 3]
    r = np.linalg.norm(dirs, axis=1)
    again, _ = raycast(sc.world, T_wl[:, :3, 3], dirs / r[:, None], spec.max_range_m)
    np.testing.assert_allclose(again, r, rtol=1e-9)
    np.testing.assert_allclose(r, scan.ranges_true_m, rtol=1e-12)
    offsets = scan.stamps_ns - scan.start_ns
    assert offsets.min() == 0 and offsets.max() < spec.period_ns


def test_raycast_primitives_and_sector_culling_agree_with_geometry():
    w = World("unit")
    w.add_plane(0.0)
    w.add_box((4.0, -1.0, 0.0), (5.0, 1.0, 2.0))
    w.add_cylinder(0.0, 3.0, 0.5, 0.0, 2.0)
    o = np.array([0.0, 0.0, 1.0])
    dirs = np.array([[1.0, 0, 0], [0, 1.0, 0], [0, 0, -1.0], [-1.0, 0, 0], [0, 0, 1.0]])
    r, ids = raycast(w, o, dirs)
    np.testing.assert_allclose(r[:3], [4.0, 2.5, 1.0])
    assert np.isinf(r[3:]).all() and list(ids) == [0, 1, 2, -1, -1]
    r_cut, _ = raycast(w, o, dirs, max_range_m=3.0)
    assert np.isinf(r_cut[0]) and r_cut[1] == pytest.approx(2.5)
    # many rays (sector culling on) give the same answer as one ray at a time
    rng = np.random.default_rng(1)
    d = rng.normal(size=(2000, 3))
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    many, _ = raycast(w, o, d)
    one = np.array([raycast(w, o, d[i:i + 1])[0][0] for i in range(0, 2000, 37)])
    np.testing.assert_array_equal(many[::37], one)


def test_footprint_clearance_sign():
    w = World("unit")
    w.add_box((0.0, 0.0, 0.0), (1.0, 1.0, 1.0))
    w.add_box((5.0, 5.0, 2.5), (6.0, 6.0, 2.8))  # hanging above the body: ignored
    d = footprint_clearance(w, np.array([[2.0, 0.5], [0.5, 0.5], [5.5, 5.5]]), 0.0, 1.9)
    np.testing.assert_allclose(d[:2], [1.0, -0.5])
    assert d[2] > 4.0


@pytest.mark.parametrize("start", ["still", "moving"])
@pytest.mark.parametrize("name", SCENARIOS)
def test_paths_never_enter_an_obstacle(name, start):
    sc = build_scenario(name, start=start)
    t = np.arange(0.0, 150.0, 0.05)  # more than a lap of every closed path but the rover's
    t_long = np.arange(150.0, 3600.0, 0.5)  # up to the longest --duration allowed (the corridor is open)
    xy = sc.trajectory.state(np.concatenate([t, t_long])).position_m[:, :2]
    clearance = footprint_clearance(sc.world, xy, *sc.body_z_m)
    assert clearance.min() > sc.clearance_m
    if sc.trajectory.path.closed:  # the rover (1.5 m/s) laps its 509 m in 6 min
        lap_s = 600.0 if name == "rover" else 150.0
        assert sc.trajectory.progress(np.array([lap_s]))[0][0] > sc.trajectory.path.length_m * 0.9


def test_trajectory_building_blocks_are_exact():
    path = Path2D(np.array([[0.0, 0.0], [4.0, 0.0], [4.0, 3.0], [0.0, 3.0]]))
    traj = Trajectory(path, Progress(1.0), yaw_offset=Sines((0.3,), (1.0,), (0.0,)))
    st = traj.state(np.array([0.0, 1.0]))
    np.testing.assert_allclose(st.position_m[0, :2], [0.0, 0.0], atol=1e-12)
    np.testing.assert_allclose(st.velocity_mps, 0.0, atol=1e-12)
    R = st.R_world_base
    np.testing.assert_allclose(np.einsum("nij,nkj->nik", R, R), np.tile(np.eye(3), (2, 1, 1)), atol=1e-12)


def test_handheld_defeats_constant_velocity_but_not_the_gyro():
    """Per sweep, extrapolating the previous sweep's rotation (constant velocity) is degrees off on the
    handheld path; integrating the (noiseless) gyro over the sweep is within hundredths of a degree."""
    sc = build_scenario("handheld")
    starts = np.arange(3.0, 20.0, 0.1)
    T = sc.trajectory.poses(np.concatenate([starts - 0.1, starts, starts + 0.1])).reshape(3, len(starts), 4, 4)
    R_prev = np.einsum("nji,njk->nik", T[0, :, :3, :3], T[1, :, :3, :3])
    R_cur = np.einsum("nji,njk->nik", T[1, :, :3, :3], T[2, :, :3, :3])
    cv_err_deg = np.degrees(np.linalg.norm(so3_log(np.einsum("nji,njk->nik", R_prev, R_cur)), axis=1))
    assert np.median(cv_err_deg) > 3.0
    imu = synthesize_imu(sc.trajectory, sc.T_base_imu, ImuSpec(), 0, 21 * NS, 0, rng=None)
    R_bi = sc.T_base_imu[:3, :3]
    for s, R_true in zip(starts[::17], R_cur[::17]):
        k0 = int(round(s * 200))
        R = np.eye(3)
        for k in range(k0, k0 + 20):
            w0, w1 = imu.gyro_radps[k], imu.gyro_radps[k + 1]
            R = R @ so3_exp((w0 + w1) / 2 * 0.005 + np.cross(w0, w1) * 0.005**2 / 12)
        R_base = R_bi @ R @ R_bi.T
        assert np.degrees(np.linalg.norm(so3_log(R_base.T @ R_true))) < 0.05


def test_imu_read_back_from_the_log_integrates_to_the_tum_ground_truth(tmp_path):
    """The same check end to end: /imu and /tf_static as written to a bag, ground truth from x.gt.tum."""
    from lio_cli.io.messages.decode import decode_tf, imu_sample
    from lio_cli.io.logs.reader import open_log
    from lio_cli.io.files.trajectory import read_tum
    from lio_cli.simulation import output_paths, simulate

    out = tmp_path / "ideal.bag"
    simulate("handheld", out, duration_s=10.0, seed=0, noise_scale=0.0, columns=16)
    gt_stamps, gt_poses = read_tum(output_paths(out)[0])
    with open_log(out) as log:
        T_bi = next(tr.pose for _, _, _, m in log.messages(["/tf_static"]) for tr in decode_tf(m) if tr.child == "imu")
        samples = [imu_sample(m) for _, _, _, m in log.messages(["/imu"])]
    stamps = np.array([s[0] for s in samples])
    gyro, accel = np.array([s[1] for s in samples]), np.array([s[2] for s in samples])
    assert stamps[0] == gt_stamps[0] and stamps[-1] == gt_stamps[-1]
    # starts at rest: the initial velocity is zero
    T_wi = _integrate_imu(stamps, gyro, accel, gt_poses[0] @ T_bi, np.zeros(3))
    T_wb = T_wi @ inv_pose(T_bi)
    assert np.linalg.norm(T_wb[:3, 3] - gt_poses[-1][:3, 3]) < POS_TOL_M
    assert _rot_err_deg(T_wb, gt_poses[-1]) < ROT_TOL_DEG


def assert_derivatives_match(traj, t: np.ndarray, alpha_atol: float, h_s: float = 1e-5):
    """The trajectory's velocity, acceleration, body rate and angular acceleration at ``t`` against central
    differences of its positions, velocities, attitudes and rates; the state at ``t`` for further checks."""
    st, sp, sm = (traj.state(x) for x in (t, t + h_s, t - h_s))
    h2 = 2 * h_s
    np.testing.assert_allclose(st.velocity_mps, (sp.position_m - sm.position_m) / h2, atol=1e-6)
    np.testing.assert_allclose(st.accel_mps2, (sp.velocity_mps - sm.velocity_mps) / h2, atol=1e-4)
    W = np.einsum("nji,njk->nik", st.R_world_base, (sp.R_world_base - sm.R_world_base) / h2)
    np.testing.assert_allclose(st.omega_base_radps, np.stack([W[:, 2, 1], W[:, 0, 2], W[:, 1, 0]], axis=1), atol=1e-6)
    np.testing.assert_allclose(st.alpha_base_radps2, (sp.omega_base_radps - sm.omega_base_radps) / h2, atol=alpha_atol)
    return st
