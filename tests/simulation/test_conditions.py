"""Real-log conditions of `lio simulate`: moving start, IMU mounting, ground truth as Odometry, IMU driver
starting after the first scan, no /tf_static, no wheels, explicit wheel and IMU errors; each checked
physically against the exact trajectory."""

from __future__ import annotations

import json

import numpy as np
import pytest

from lio_cli.cli.app import main
from lio_cli.geometry import so3_log
from lio_cli.io.messages.decode import decode_tf, imu_sample
from lio_cli.io.logs.reader import open_log
from lio_cli.io.sensors.sources import load_trajectory
from lio_cli.io.files.trajectory import read_tum
from lio_cli.simulation import SCENARIOS, build_scenario, metrics_path_for, output_paths, simulate
from lio_cli.simulation.motion import ypr_to_matrix
from lio_cli.simulation.sensors import GRAVITY_MPS2, imu_truth

NS = 1_000_000_000
START_NS = 1_700_000_000 * NS
FD_H_S = 2e-4  # central differences of the exact trajectory: truncation ~1e-6
RATE_TOL = 1e-5
ACCEL_TOL = 1e-3
CRUISE_MPS = {"handheld": (0.7, 1.8), "drive": (6.0, 9.0), "corridor": (0.85, 1.15), "planar": (0.3, 1.1),
              "rover": (1.0, 2.0), "drone": (3.0, 5.0)}  # speeds at cruise


def _stamp(msg) -> int:
    return msg.header.stamp.sec * NS + msg.header.stamp.nanosec


def _truth(out):
    return json.loads(output_paths(out)[1].read_text())


def _fd_kinematics(traj, t_s, r_base):
    """World acceleration of the point ``r_base`` on the body and the body rate, by central differences of
    the poses alone (independent of the simulator's analytic derivatives)."""
    h = FD_H_S
    T = traj.poses(np.concatenate([t_s - h, t_s, t_s + h])).reshape(3, len(t_s), 4, 4)
    p = T[:, :, :3, 3] + np.einsum("knij,j->kni", T[:, :, :3, :3], r_base)
    acc = (p[2] - 2 * p[1] + p[0]) / h**2
    dR = np.einsum("nji,njk->nik", T[0, :, :3, :3], T[2, :, :3, :3])
    omega = np.stack([so3_log(R) for R in dR]) / (2 * h)
    return T[1], acc, omega


@pytest.mark.parametrize("name", SCENARIOS)
def test_moving_start_is_in_motion_at_t0(name):
    still, moving = build_scenario(name), build_scenario(name, start="moving")
    assert moving.rest_s == 0.0 and still.rest_s == 1.5
    t = np.arange(0.0, 120.0, 0.05)
    st = moving.trajectory.state(t)
    speed = np.linalg.norm(st.velocity_mps, axis=1)
    lo, hi = CRUISE_MPS[name]
    assert lo <= speed[0] <= hi and lo - 0.1 <= speed.min() and speed.max() <= hi + 0.1
    np.testing.assert_allclose(np.linalg.norm(still.trajectory.state(np.array([0.0])).velocity_mps), 0.0, atol=1e-12)
    if name == "handheld":  # walking with full yaw sweeps from the first sample
        assert abs(st.omega_base_radps[0, 2]) > 2.0
    if name == "drive":  # cruising straight: the IMU alone looks still for the first half second
        t0 = np.arange(0.0, 0.5, 0.005)
        gyro, accel = imu_truth(moving.trajectory, moving.T_base_imu, t0)
        assert np.linalg.norm(gyro, axis=1).max() < 0.01
        assert np.abs(np.linalg.norm(accel, axis=1) - 9.81).max() < 0.05


def test_moving_start_log_ground_truth_and_wheels_agree_on_the_initial_speed(tmp_path):
    out = tmp_path / "c.bag"
    simulate("corridor", out, duration_s=1.0, seed=0, columns=16, start="moving", noise_scale=0.0)
    init = _truth(out)["conditions"]["initial_state"]
    assert _truth(out)["conditions"]["start"] == "moving" and _truth(out)["rest_s"] == 0.0
    gt_ns, gt_poses = read_tum(output_paths(out)[0])
    assert gt_ns[0] == START_NS
    v_fd = (gt_poses[1, :3, 3] - gt_poses[0, :3, 3]) / 0.01
    np.testing.assert_allclose(v_fd, init["velocity_mps"], atol=2e-3)
    assert init["speed_mps"] == pytest.approx(1.1, abs=0.01)
    with open_log(out) as log:
        wheel = [m for _, _, _, m in log.messages(["/wheel/odom"])]
        imu = [imu_sample(m) for _, _, _, m in log.messages(["/imu"])]
        first_scan = next(m for _, _, _, m in log.messages(["/points"]))
    assert _stamp(wheel[0]) == START_NS and wheel[0].twist.twist.linear.x == pytest.approx(init["velocity_base_mps"][0], abs=1e-9)
    assert wheel[0].twist.twist.angular.z == pytest.approx(init["omega_base_radps"][2], abs=1e-9)
    assert imu[0][0] == START_NS and abs(imu[0][1][2]) > 0.05  # the corridor weave: turning from the first sample
    assert _stamp(first_scan) == START_NS


@pytest.mark.parametrize("rpy_deg", [(180.0, 0.0, 90.0), (0.0, 0.0, 30.0), (-35.0, 60.0, 170.0)])
def test_rotated_imu_reads_the_base_specific_force_and_rate(tmp_path, rpy_deg):
    lever = np.array([0.3, -0.2, 0.1])
    out = tmp_path / "h.mcap"
    simulate("handheld", out, duration_s=0.6, seed=0, columns=16, start="moving", noise_scale=0.0,
             imu_rotation_deg=rpy_deg, imu_lever_arm_m=tuple(lever))
    roll, pitch, yaw = np.radians(rpy_deg)
    R_bi = ypr_to_matrix(np.array(yaw), np.array(pitch), np.array(roll))
    truth = _truth(out)
    np.testing.assert_allclose(np.asarray(truth["T_base_imu"])[:3, :3], R_bi, atol=1e-12)
    assert truth["conditions"]["imu_rotation_rpy_deg"] == list(rpy_deg)
    with open_log(out) as log:
        tf = {t.child: t.pose for _, _, _, m in log.messages(["/tf_static"]) for t in decode_tf(m)}
        samples = [imu_sample(m) for _, _, _, m in log.messages(["/imu"])]
    np.testing.assert_allclose(tf["imu"][:3, :3], R_bi, atol=1e-9)
    np.testing.assert_allclose(tf["imu"][:3, 3], lever, atol=1e-9)
    stamps = np.array([s[0] for s in samples])
    gyro, accel = np.array([s[1] for s in samples]), np.array([s[2] for s in samples])
    T_wb, acc_w, omega = _fd_kinematics(build_scenario("handheld", start="moving").trajectory,
                                        (stamps - START_NS) * 1e-9, lever)
    np.testing.assert_allclose(gyro @ R_bi.T, omega, atol=RATE_TOL)
    f_base = np.einsum("nji,nj->ni", T_wb[:, :3, :3], acc_w - GRAVITY_MPS2)
    np.testing.assert_allclose(accel @ R_bi.T, f_base, atol=ACCEL_TOL)
    assert np.abs(omega[:, 2]).max() > 2.0  # really sweeping, so a wrong lever arm or rotation would show


@pytest.mark.parametrize("twist", [False, True])
def test_odometry_ground_truth_reads_back_as_the_tum_poses(tmp_path, twist):
    out = tmp_path / "p.bag"
    simulate("planar", out, duration_s=1.0, seed=0, start="moving", gt_type="odometry", gt_topic="/vicon/base",
             gt_twist=twist)
    gt_ns, gt_poses = read_tum(output_paths(out)[0])
    loaded = load_trajectory(f"{out}:/vicon/base")
    np.testing.assert_array_equal(loaded.stamps_ns, gt_ns)
    np.testing.assert_allclose(loaded.poses, gt_poses, atol=1e-9)
    with open_log(out) as log:
        assert log.topics["/vicon/base"].msgtype == "nav_msgs/msg/Odometry" and "/ground_truth" not in log.topics
        msgs = [m for _, _, _, m in log.messages(["/vicon/base"])]
    assert msgs[0].header.frame_id == "world" and msgs[0].child_frame_id == "base"
    lin = np.array([[m.twist.twist.linear.x, m.twist.twist.linear.y, m.twist.twist.linear.z] for m in msgs])
    ang = np.array([[m.twist.twist.angular.x, m.twist.twist.angular.y, m.twist.twist.angular.z] for m in msgs])
    if not twist:  # like many datasets and simulators: the twist is all zero
        assert not lin.any() and not ang.any()
    else:  # REP 105: in the child frame
        st = build_scenario("planar", start="moving").trajectory.state((gt_ns - START_NS) * 1e-9)
        np.testing.assert_allclose(lin, np.einsum("nji,nj->ni", st.R_world_base, st.velocity_mps), atol=1e-9)
        np.testing.assert_allclose(ang, st.omega_base_radps, atol=1e-9)
        assert lin[0, 0] > 0.3
    gt = _truth(out)["conditions"]["ground_truth"]
    assert gt == {"type": "odometry", "topic": "/vicon/base", "twist": "true" if twist else "zero"}


def test_imu_driver_starting_late_puts_the_first_scan_before_the_first_imu_message(tmp_path):
    out = tmp_path / "late.bag"
    simulate("handheld", out, duration_s=0.5, seed=1, columns=16, imu_start_delay_s=0.15, imu_time_offset_s=-0.015)
    with open_log(out) as log:
        order = [(topic, t, m) for topic, _, t, m in log.messages()]
    sensors = [o[0] for o in order if o[0] in ("/points", "/imu")]
    assert sensors[0] == "/points"  # recorded at the end of the first sweep, 0.1 s, before the IMU starts
    first_scan = next(m for topic, _, m in order if topic == "/points")
    first_imu = next(m for topic, _, m in order if topic == "/imu")
    assert _stamp(first_scan) == START_NS and _stamp(first_imu) == START_NS + 150_000_000
    cond = _truth(out)["conditions"]
    assert cond["first_scan_before_first_imu"] is True and cond["first_imu_stamp_ns"] == START_NS + 150_000_000
    assert cond["imu_start_delay_s"] == 0.15 and _truth(out)["imu"]["imu_time_offset_ns"] == -15_000_000


def test_no_tf_static_no_wheel_and_the_default_truth_keeps_its_keys(tmp_path):
    out = tmp_path / "c.mcap"
    res = simulate("corridor", out, duration_s=0.5, seed=0, columns=16, tf_static=False, wheel=False)
    assert set(res.topics) == {"/imu", "/points", "/ground_truth"}
    truth = _truth(out)
    assert truth["wheel"] is None and truth["conditions"]["tf_static"] is False and truth["conditions"]["wheel"] is False
    np.testing.assert_allclose(truth["T_base_imu"], build_scenario("corridor").T_base_imu, atol=1e-12)
    plain = tmp_path / "plain.mcap"
    simulate("corridor", plain, duration_s=0.5, seed=0, columns=16)
    assert "conditions" not in _truth(plain) and "gps" not in _truth(plain)  # as before these options existed
    assert json.loads(metrics_path_for(plain).read_text())["options"]["start"] == "still"


def test_cli_conditions_and_error_model_reach_the_log_and_truth(tmp_path, capsys):
    out = tmp_path / "p.mcap"
    rc = main([str(a) for a in (
        "simulate", "planar", out, "--duration", 1.0, "--noise-scale", 0, "--start", "moving",
        "--imu-rotation", "0,0,30", "--imu-lever-arm", "0.1,0.2,0.3", "--gt-type", "odometry", "--gt-topic", "/odom_gt",
        "--no-tf-static", "--wheel-radius-scale", "1.02,0.99", "--wheel-baseline-scale", "1.05",
        "--accel-bias", "0.01,0.02,0.03", "--gyro-bias", "0.001,0,0", "--accel-walk", "1e-4", "--gyro-walk", "1e-5",
        "--gps-rate", "2", "--gps-origin", "-33.8568,151.2153,5", "--gps-noise", "0.5,1", "--gps-outage", "0",
        "--gps-invalid", "0", "--quiet")])
    assert rc == 0, capsys.readouterr().err
    truth = _truth(out)
    assert truth["conditions"]["start"] == "moving" and truth["conditions"]["tf_static"] is False
    q = np.asarray(truth["T_base_imu"])
    assert np.degrees(np.linalg.norm(so3_log(q[:3, :3]))) == pytest.approx(30.0, abs=1e-9)
    np.testing.assert_allclose(q[:3, 3], [0.1, 0.2, 0.3])
    w = truth["wheel"]
    assert (w["radius_scale_left"], w["radius_scale_right"], w["baseline_scale"]) == (1.02, 0.99, 1.05)
    assert truth["imu"]["accel_bias_mps2"] == [0.01, 0.02, 0.03] and truth["imu"]["gyro_bias_radps"] == [0.001, 0.0, 0.0]
    assert (truth["imu"]["accel_bias_walk"], truth["imu"]["gyro_bias_walk"]) == (0.0, 0.0)  # noise scale 0
    assert truth["gps"]["origin"] == {"lat_deg": -33.8568, "lon_deg": 151.2153, "alt_m": 5.0}
    assert truth["gps"]["outage"] is None and truth["gps"]["invalid"] == 0 and truth["gps"]["messages"] == 3
    with open_log(out) as log:
        assert set(log.topics) == {"/imu", "/scan", "/wheel/odom", "/odom_gt", "/gps/fix"}
        imu = [m for _, _, _, m in log.messages(["/imu"])]
        wheel = [m for _, _, _, m in log.messages(["/wheel/odom"])]
    a = imu[0].linear_acceleration
    assert a.x != 0.0 or a.y != 0.0  # the explicit bias is not scaled away by --noise-scale 0
    # wheel odometry with the true radii and baseline off the nominal ones (no slip at noise scale 0)
    sc = build_scenario("planar", start="moving")
    st = sc.trajectory.state(np.array([(_stamp(wheel[-1]) - START_NS) * 1e-9]))
    v, om = float(st.velocity_mps[0] @ st.R_world_base[0][:, 0]), float(st.omega_base_radps[0, 2])
    L = sc.wheels.baseline_m
    vR, vL = (v + om * L * 1.05 / 2) / 0.99, (v - om * L * 1.05 / 2) / 1.02
    assert wheel[-1].twist.twist.linear.x == pytest.approx((vR + vL) / 2, abs=1e-9)
    assert wheel[-1].twist.twist.angular.z == pytest.approx((vR - vL) / L, abs=1e-9)


@pytest.mark.parametrize("argv, message", [
    (("--imu-rotation", "1,2"), "--imu-rotation needs 3 comma-separated numbers (got '1,2')"),
    (("--gps-origin", "48,x,5"), "--gps-origin needs 3 comma-separated numbers (got '48,x,5')"),
    (("--start", "flying"), "Invalid value for '--start': 'flying' is not one of 'still', 'moving', 'accelerating'; see "
                            "'lio simulate --help'"),
    (("--gt-type", "tf"), "Invalid value for '--gt-type': 'tf' is not one of 'pose', 'odometry', 'none'; see "
                          "'lio simulate --help'"),
    (("--gt-twist",), "--gt-twist fills the twist of nav_msgs/Odometry ground truth; add --gt-type odometry"),
    (("--gt-topic", "truth"), "--gt-topic must be a topic name starting with / (got 'truth')"),
    (("--wheel",), "--wheel: the handheld scenario has no wheels"),
    (("--imu-start-delay", "30"), "--imu-start-delay must be >= 0 and shorter than the run (got 30.0)"),
    (("--gps-origin", "91,0,0"), "--gps-origin must be LAT,LON,ALT with |lat| < 90, |lon| <= 180, alt -1000..10000 m "
                                 "(got 91.0,0.0,0.0)"),
    (("--accel-walk", "-1"), "--accel-walk must be >= 0 (got -1.0)"),
    (("--tilt-scale", "6"), "--tilt-scale must be within 0..5 (got 6.0)"),
])
def test_bad_condition_options_exit_2_with_one_line(tmp_path, capsys, monkeypatch, argv, message):
    monkeypatch.chdir(tmp_path)
    rc = main(["simulate", "handheld", "x.bag", "--duration", "2", *argv])
    out, err = capsys.readouterr()
    assert (rc, out, err) == (2, "", f"lio: error: {message}\n")
    assert not any(tmp_path.iterdir())


def test_tilt_scale_multiplies_the_roll_and_pitch_sway_and_the_truth_rebuilds_it(tmp_path):
    """--tilt-scale 3: the ground truth's roll and pitch are 3x those of the same seed's walk, its yaw and path
    the same; truth.json names the scale and the de-skew truth rebuilt from it gives the logged poses."""
    from lio_cli.simulation.deskew_truth import TrueMotion

    runs = {k: simulate("handheld", tmp_path / f"w{k}.bag", "ros1", duration_s=4.0, seed=3, tilt_scale=k)
            for k in (1.0, 3.0)}
    rpy = {}
    for k, sim in runs.items():
        gt = load_trajectory(sim.gt_path)
        R = gt.poses[:, :3, :3]
        rpy[k] = np.column_stack([np.arctan2(R[:, 2, 1], R[:, 2, 2]), -np.arcsin(R[:, 2, 0])])
        if k == 3.0:
            assert _truth(sim.log_path)["conditions"]["tilt_scale"] == 3.0
            motion = TrueMotion(sim.truth_path)
            assert motion.poses(gt.stamps_ns) == pytest.approx(gt.poses, abs=1e-6)
        else:
            assert "conditions" not in _truth(sim.log_path)  # the default keeps the historical truth file
        xy = gt.poses[:, :2, 3]
    assert np.abs(rpy[1.0]).max() > 0.02  # the walk sways
    assert rpy[3.0] == pytest.approx(3.0 * rpy[1.0], abs=2e-3)  # roll and pitch small: angles scale too
    assert load_trajectory(runs[1.0].gt_path).poses[:, :2, 3] == pytest.approx(xy, abs=1e-9)
