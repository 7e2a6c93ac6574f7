"""Stops mid-log (`lio simulate --stop AT:SECONDS`): the platform brakes, stands exactly still and drives on;
every sensor sees it, the IMU still integrates to the truth, truth.json and the metrics record it."""

from __future__ import annotations

import hashlib
import json

import numpy as np
import pytest

from lio_cli.cli.app import main
from lio_cli.geometry import inv_pose
from lio_cli.io.files.trajectory import read_tum
from lio_cli.io.logs.reader import open_log
from lio_cli.io.messages.decode import imu_sample
from lio_cli.simulation import SCENARIOS, build_scenario, metrics_path_for, output_paths, simulate
from lio_cli.simulation.sensors import GRAVITY_MPS2, ImuSpec, synthesize_imu, wheel_odometry
from lio_cli.simulation.stops import RAMP_S

from .test_fuse_conditions import assert_refused
from .test_physics import POS_TOL_M, ROT_TOL_DEG, _integrate_imu, _rot_err_deg, assert_derivatives_match

NS = 1_000_000_000
START_NS = 1_700_000_000 * NS
STILL_TOL = 1e-9  # "exactly still": velocities and rates (they are exact zeros; poses agree to rounding)


def _stamp(msg) -> int:
    return msg.header.stamp.sec * NS + msg.header.stamp.nanosec


@pytest.mark.parametrize("name", SCENARIOS)
def test_ground_truth_stands_still_inside_a_stop_and_resumes_where_it_paused(name):
    at, seconds = 8.0, 2.5
    plain, stopped = build_scenario(name), build_scenario(name, stops=((at, seconds),))
    t = np.linspace(at, at + seconds, 51)
    st = stopped.trajectory.state(t)
    for moving in (st.velocity_mps, st.accel_mps2, st.omega_base_radps, st.alpha_base_radps2):
        np.testing.assert_allclose(moving, 0.0, atol=STILL_TOL)
    np.testing.assert_allclose(st.poses, np.broadcast_to(st.poses[0], st.poses.shape), atol=STILL_TOL)
    # before braking it is the plain motion; after driving off, the plain motion SECONDS + RAMP_S later
    before, after = np.linspace(0.0, at - RAMP_S, 40), np.linspace(at + seconds + RAMP_S, 30.0, 40)
    np.testing.assert_array_equal(stopped.trajectory.poses(before), plain.trajectory.poses(before))
    a, b = stopped.trajectory.state(after), plain.trajectory.state(after - seconds - RAMP_S)
    np.testing.assert_allclose(a.poses, b.poses, atol=1e-9)
    np.testing.assert_allclose(a.velocity_mps, b.velocity_mps, atol=1e-9)
    assert np.linalg.norm(plain.trajectory.state(np.array([at])).velocity_mps) > 0.3  # it did have to stop


def test_warped_derivatives_match_finite_differences_through_the_ramps():
    traj = build_scenario("handheld", stops=((6.0, 1.0), (13.0, 2.0))).trajectory
    assert_derivatives_match(traj, np.linspace(2.0, 20.0, 700), alpha_atol=1e-3)


@pytest.mark.parametrize("name", ["handheld", "drive"])
def test_noiseless_imu_integrates_to_ground_truth_across_a_stop(name):
    sc = build_scenario(name, stops=((5.0, 1.5),))
    imu = synthesize_imu(sc.trajectory, sc.T_base_imu, ImuSpec(), 0, 14 * NS, 0, rng=None)
    st = sc.trajectory.state(np.array([0.0, 14.0]))
    T_bi = sc.T_base_imu
    T_wb = _integrate_imu(imu.stamps_ns, imu.gyro_radps, imu.accel_mps2, st.poses[0] @ T_bi, np.zeros(3)) @ inv_pose(T_bi)
    assert np.linalg.norm(st.position_m[1] - st.position_m[0]) > 5.0
    assert np.linalg.norm(T_wb[:3, 3] - st.position_m[1]) < POS_TOL_M
    assert _rot_err_deg(T_wb, st.poses[1]) < ROT_TOL_DEG


def test_slip_inside_a_stop_leaves_the_wheels_at_rest():
    sc = build_scenario("planar", stops=((6.0, 3.0),))
    sc.wheels.slip_start_s, sc.wheels.slip_duration_s, sc.wheels.slip_left, sc.wheels.slip_right = 6.5, 2.0, 0.3, 0.1
    wheel = wheel_odometry(sc.trajectory, sc.wheels, 0, 12 * NS, 0)
    inside = (wheel.stamps_ns >= 6 * NS) & (wheel.stamps_ns <= 9 * NS)
    assert (wheel.linear_mps[inside] == 0.0).all() and (wheel.angular_radps[inside] == 0.0).all()
    np.testing.assert_array_equal(wheel.poses_odom_base[inside], np.broadcast_to(wheel.poses_odom_base[inside][0],
                                                                                 (inside.sum(), 4, 4)))


def test_log_at_rest_reads_gravity_zero_rates_and_zero_wheel_speed(tmp_path):
    """End to end, ideal sensors: inside the stop the gyro reads exactly 0, the accelerometer gravity in the
    IMU frame, the wheels 0; the poses freeze; truth.json, the metrics and the de-skew truth record the stop."""
    from lio_cli.simulation.deskew_truth import TrueMotion

    out = tmp_path / "r.mcap"
    rc = main(["simulate", "rover", str(out), "--duration", "15", "--no-lidar", "--noise-scale", "0",
               "--stop", "13:10", "--stop", "5:1", "--quiet"])
    assert rc == 0
    gt_path, truth_path = output_paths(out)
    truth = json.loads(truth_path.read_text())
    assert [(s["start_s"], s["end_s"], s["duration_s"]) for s in truth["stops"]] == [(5.0, 6.0, 1.0), (13.0, 23.0, 10.0)]
    first = truth["stops"][0]
    assert (first["start_ns"], first["end_ns"]) == (START_NS + 5 * NS, START_NS + 6 * NS)
    assert (first["brake_start_s"], first["drive_off_end_s"]) == (5.0 - RAMP_S, 6.0 + RAMP_S)
    assert truth["stops"][1]["end_ns"] > truth["end_ns"]  # the log ends parked
    assert "exactly still" in truth["stops_meaning"] and truth["conditions"]["start"] == "still"
    assert json.loads(metrics_path_for(out).read_text())["options"]["stops"] == [[5.0, 1.0], [13.0, 10.0]]
    R_bi = np.asarray(truth["T_base_imu"])[:3, :3]
    windows = [(START_NS + 5 * NS, START_NS + 6 * NS), (START_NS + 13 * NS, START_NS + 15 * NS)]
    with open_log(out) as log:
        imu = [imu_sample(m) for _, _, _, m in log.messages(["/imu"])]
        wheel = [m for _, _, _, m in log.messages(["/wheel/odom"])]
    gt_ns, gt_poses = read_tum(gt_path)
    for lo, hi in windows:
        rows = [s for s in imu if lo <= s[0] <= hi]
        gyro, accel = np.array([s[1] for s in rows]), np.array([s[2] for s in rows])
        assert len(rows) >= 200 and (gyro == 0.0).all()
        inside = (gt_ns >= lo) & (gt_ns <= hi)
        R_wb = gt_poses[inside][0][:3, :3]
        np.testing.assert_allclose(accel, np.broadcast_to(-GRAVITY_MPS2 @ R_wb @ R_bi, accel.shape), atol=1e-9)
        np.testing.assert_array_equal(gt_poses[inside], np.broadcast_to(gt_poses[inside][0], gt_poses[inside].shape))
        still = [m for m in wheel if lo <= _stamp(m) <= hi]
        assert len(still) >= 50
        assert all(m.twist.twist.linear.x == 0.0 and m.twist.twist.angular.z == 0.0 for m in still)
    assert max(abs(m.twist.twist.linear.x) for m in wheel if _stamp(m) < START_NS + 4 * NS) > 1.0
    assert TrueMotion(truth_path).poses(gt_ns) == pytest.approx(gt_poses, abs=1e-6)


def test_same_stops_same_bytes_and_the_warp_moves_only_what_follows(tmp_path):
    args = ["--duration", "9", "--no-lidar", "--seed", "4", "--gps", "--quiet"]
    digests = []
    for name, stops in (("a.mcap", ["--stop", "6:2"]), ("b.mcap", ["--stop", "6:2"]), ("c.mcap", [])):
        assert main(["simulate", "drive", str(tmp_path / name), *args, *stops]) == 0
        digests.append([hashlib.sha256(p.read_bytes()).hexdigest() for p in (tmp_path / name, *output_paths(tmp_path / name))])
    assert digests[0] == digests[1] and digests[0][0] != digests[2][0]
    (ns_a, poses_a), (ns_c, poses_c) = (read_tum(output_paths(tmp_path / n)[0]) for n in ("a.mcap", "c.mcap"))
    before = ns_a <= START_NS + int((6.0 - RAMP_S) * NS)
    np.testing.assert_array_equal(poses_a[before], poses_c[before])


@pytest.mark.parametrize("scenario, argv, message", [
    ("drive", ("--stop", "20"), "--stop needs AT:SECONDS, two numbers of seconds such as 20:5 (got '20')"),
    ("drive", ("--stop", "a:b"), "--stop needs AT:SECONDS, two numbers of seconds such as 20:5 (got 'a:b')"),
    ("drive", ("--stop", "20:inf"), "--stop needs AT:SECONDS, two numbers of seconds such as 20:5 (got '20:inf')"),
    ("drive", ("--stop", "20:-5"), "--stop 20:-5: SECONDS must be positive"),
    ("drive", ("--stop", "-5:3"), "--stop -5:3: braking takes the 3 s before AT and the platform starts moving at "
                                  "1.5 s, so AT must be at least 4.5"),
    ("drive", ("--stop", "4:3"), "--stop 4:3: braking takes the 3 s before AT and the platform starts moving at "
                                 "1.5 s, so AT must be at least 4.5"),
    ("drive", ("--stop", "30:5", "--stop", "20:5"), "--stop 20:5 and --stop 30:5 overlap: a stop drives off over the "
                                                    "3 s after AT + SECONDS and brakes over the 3 s before AT, so the "
                                                    "later AT must be at least 31"),
    ("drive", ("--stop", "45:5"), "--stop 45:5: AT must be before the run's end at 45 s"),
    ("static", ("--stop", "20:5"), "--stop does not apply to the static scenario (an IMU at rest, no LiDAR, wheels "
                                   "or GPS)"),
])
def test_bad_stops_exit_2_with_one_line(tmp_path, capsys, monkeypatch, scenario, argv, message):
    assert_refused(tmp_path, capsys, monkeypatch, ["simulate", scenario, "x.bag", "--duration", "45", *argv], message)


def test_a_moving_start_may_brake_from_the_first_sample(tmp_path):
    sc = build_scenario("corridor", start="moving", stops=((RAMP_S, 1.0),))
    st = sc.trajectory.state(np.array([0.0, RAMP_S + 0.5]))
    assert np.linalg.norm(st.velocity_mps[0]) > 0.8 and np.linalg.norm(st.velocity_mps[1]) == 0.0
    out = tmp_path / "m.mcap"  # the library takes the pairs in any order and records them in time order
    simulate("corridor", out, duration_s=11.0, start="moving", lidar=False, stops=[(10.0, 1.0), (RAMP_S, 1.0)])
    assert json.loads(metrics_path_for(out).read_text())["options"]["stops"] == [[3.0, 1.0], [10.0, 1.0]]


def test_laser_scans_inside_a_stop_are_alike(tmp_path):
    out = tmp_path / "p.bag"
    simulate("planar", out, duration_s=8.0, noise_scale=0.0, columns=90, stops=((5.0, 2.0),))
    with open_log(out) as log:
        scans = {_stamp(m): np.asarray(m.ranges) for _, _, _, m in log.messages(["/scan"])}
    inside = [r for t, r in scans.items() if START_NS + 5 * NS <= t and t + NS // 10 <= START_NS + 7 * NS]
    assert len(inside) >= 19 and all(np.array_equal(r, inside[0], equal_nan=True) for r in inside)
    moving = [r for t, r in scans.items() if START_NS + 3 * NS <= t < START_NS + 4 * NS]
    assert not np.array_equal(moving[0], moving[-1], equal_nan=True)
