"""Hills for ground platforms (`lio simulate --hills AMPLITUDE:WAVELENGTH`): the base rides the ground's height
along the path and pitches with its grade, exactly: the IMU integrates back to the truth, the wheels measure
the speed along the slope, a stop on a slope stands still with gravity tilted in the base, GPS altitude follows
the hills; truth.json records them and bad values are refused in one line."""

from __future__ import annotations

import json

import numpy as np
import pytest

from lio_cli.cli.app import main
from lio_cli.geodesy import EnuFrame
from lio_cli.geometry import inv_pose
from lio_cli.io.files.trajectory import read_tum
from lio_cli.io.logs.reader import open_log
from lio_cli.io.messages.decode import imu_sample
from lio_cli.simulation import build_scenario, metrics_path_for, output_paths
from lio_cli.simulation.deskew_truth import TrueMotion
from lio_cli.simulation.sensors import GRAVITY_MPS2, ImuSpec, synthesize_imu

from .test_fuse_conditions import assert_refused
from .test_physics import POS_TOL_M, ROT_TOL_DEG, _integrate_imu, _rot_err_deg, assert_derivatives_match

NS = 1_000_000_000
START_NS = 1_700_000_000 * NS
A_M, L_M = 5.0, 110.0  # a grade of up to 0.286 (16 deg): the steepest allowed, so every effect is large
HILLS = f"{A_M:g}:{L_M:g}"


def _stamp(msg) -> int:
    return msg.header.stamp.sec * NS + msg.header.stamp.nanosec


def _simulate(out, scenario, *argv) -> dict:
    assert main(["simulate", scenario, str(out), "--no-lidar", "--quiet", *argv]) == 0
    return json.loads(output_paths(out)[1].read_text())


def _pitch(poses: np.ndarray) -> np.ndarray:
    """Pitch of R = Rz(yaw) Ry(pitch) Rx(roll): R[2, 0] = -sin(pitch)."""
    return -np.arcsin(poses[:, 2, 0])


def _grade(s: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(h(s), h'(s)) of the test's hills."""
    k = 2.0 * np.pi / L_M
    return A_M * np.sin(k * s), A_M * k * np.cos(k * s)


def test_derivatives_match_finite_differences_over_hills_and_through_a_stop():
    traj = build_scenario("drive", stops=((9.0, 2.0),), hills=(A_M, L_M)).trajectory
    st = assert_derivatives_match(traj, np.linspace(0.5, 20.0, 700), alpha_atol=1e-4)
    assert np.abs(st.velocity_mps[:, 2]).max() > 1.5  # it did climb and sink


@pytest.mark.parametrize("name, start, stops", [
    ("drive", "still", ((8.0, 2.0),)), ("drive", "moving", ()), ("drive", "accelerating", ((5.0, 1.0),)),
    ("rover", "moving", ()), ("corridor", "still", ()), ("planar", "moving", ((4.0, 1.0),)),
])
def test_noiseless_imu_integrates_to_the_truth_over_hills(name, start, stops):
    sc = build_scenario(name, start=start, stops=stops, hills=(A_M, 60.0 if name in ("corridor", "planar") else L_M))
    imu = synthesize_imu(sc.trajectory, sc.T_base_imu, ImuSpec(), 0, 12 * NS, 0, rng=None)
    st = sc.trajectory.state(np.array([0.0, 12.0]))
    T_bi = sc.T_base_imu
    v_imu0 = st.velocity_mps[0] + st.R_world_base[0] @ np.cross(st.omega_base_radps[0], T_bi[:3, 3])
    T_wb = _integrate_imu(imu.stamps_ns, imu.gyro_radps, imu.accel_mps2, st.poses[0] @ T_bi, v_imu0) @ inv_pose(T_bi)
    assert abs(st.position_m[1, 2] - st.position_m[0, 2]) > 0.3  # the hills moved it up or down
    assert np.linalg.norm(T_wb[:3, 3] - st.position_m[1]) < POS_TOL_M
    assert _rot_err_deg(T_wb, st.poses[1]) < ROT_TOL_DEG


def test_imu_read_back_from_a_hilly_log_integrates_to_the_tum_ground_truth(tmp_path):
    """End to end with ideal sensors and a yawed IMU: /imu from the log, T_base_imu from truth.json, the truth
    from x.gt.tum; 15 s over 90 m of road climbing and sinking by metres."""
    out = tmp_path / "h.mcap"
    truth = _simulate(out, "drive", "--hills", HILLS, "--noise-scale", "0", "--imu-rotation", "0,0,30",
                      "--duration", "15")
    gt_ns, gt_poses = read_tum(output_paths(out)[0])
    with open_log(out) as log:
        samples = [imu_sample(m) for _, _, _, m in log.messages(["/imu"])]
    stamps = np.array([s[0] for s in samples])
    gyro, accel = np.array([s[1] for s in samples]), np.array([s[2] for s in samples])
    T_bi = np.asarray(truth["T_base_imu"])
    T_wb = _integrate_imu(stamps, gyro, accel, gt_poses[0] @ T_bi, np.zeros(3)) @ inv_pose(T_bi)  # starts at rest
    assert np.linalg.norm(gt_poses[-1][:3, 3] - gt_poses[0][:3, 3]) > 50.0
    assert np.ptp(gt_poses[:, 2, 3]) > 2.0
    assert np.linalg.norm(T_wb[:3, 3] - gt_poses[-1][:3, 3]) < POS_TOL_M
    assert _rot_err_deg(T_wb, gt_poses[-1]) < ROT_TOL_DEG


def test_height_spans_the_hills_and_the_pitch_is_the_grade(tmp_path):
    """Against the same drive on flat ground: the height differs by h(s), the pitch by -atan(h'(s)) (nose up
    climbing), whatever the sway's scale; the forward axis points along the slope."""
    args = ("--duration", "20", "--tilt-scale", "2", "--noise-scale", "0")
    truth = _simulate(tmp_path / "h.mcap", "drive", "--hills", HILLS, *args)
    _simulate(tmp_path / "f.mcap", "drive", *args)
    gt_ns, hilly = read_tum(output_paths(tmp_path / "h.mcap")[0])
    _, flat = read_tum(output_paths(tmp_path / "f.mcap")[0])
    s = build_scenario("drive").trajectory.progress((gt_ns - START_NS) * 1e-9)[0]  # the path parameter
    h, h1 = _grade(s)
    assert s[-1] - s[0] > L_M  # a whole wavelength driven: the height spans 2 A
    assert np.ptp(hilly[:, 2, 3]) == pytest.approx(2 * A_M, rel=0.02)
    np.testing.assert_allclose(hilly[:, 2, 3] - flat[:, 2, 3], h, atol=2e-9)
    np.testing.assert_allclose(_pitch(hilly) - _pitch(flat), -np.arctan(h1), atol=1e-7)
    np.testing.assert_allclose(hilly[:, :2, 3], flat[:, :2, 3], atol=2e-9)  # the horizontal path is the same
    climbing = h1 > 0.1
    assert climbing.sum() > 100 and (_pitch(hilly)[climbing] < -0.05).all()  # nose up
    assert truth["hills"]["start_s_m"] == s[0] == 0.0 and truth["hills"]["start_grade"] == pytest.approx(h1[0])


def test_wheel_speed_is_the_speed_along_the_slope(tmp_path):
    """Ideal wheels: the forward speed they report is the truth's 3D speed (the horizontal speed times
    sqrt(1 + h'^2)), not its horizontal speed; without sway the base's forward axis is the slope's."""
    out = tmp_path / "w.mcap"
    _simulate(out, "drive", "--hills", HILLS, "--noise-scale", "0", "--no-wheel-errors", "--tilt-scale", "0",
              "--duration", "20")
    gt_ns, gt = read_tum(output_paths(out)[0])
    with open_log(out) as log:
        wheel = {_stamp(m): m.twist.twist.linear.x for _, _, _, m in log.messages(["/wheel/odom"])}
    dt = (gt_ns[2:] - gt_ns[:-2]) * 1e-9
    vel = (gt[2:, :3, 3] - gt[:-2, :3, 3]) / dt[:, None]  # central differences at gt_ns[1:-1]
    inner = gt_ns[1:-1]
    keep = np.isin(inner, list(wheel))
    speed = np.array([wheel[t] for t in inner[keep]])
    v3d, vh = np.linalg.norm(vel[keep], axis=1), np.linalg.norm(vel[keep, :2], axis=1)
    moving = v3d > 3.0  # the 1.5 cm bobbing (0.12 m/s up and down) is not along the slope: wz^2 / 2v apart
    assert moving.sum() > 700
    np.testing.assert_allclose(speed[moving], v3d[moving], rtol=1e-3)
    assert np.abs(speed - vh)[moving].max() > 0.2  # the grade is what made the difference
    # without sway the forward axis' rise is the slope's (sin of the grade angle), up to the bobbing's share
    fwd_up, slope = gt[1:-1][keep][moving, 2, 0], vel[keep][moving, 2] / v3d[moving]
    assert (np.abs(fwd_up - slope) < 0.125 / v3d[moving]).all() and fwd_up.max() > 0.25


def test_a_stop_on_a_slope_stands_still_with_gravity_tilted_and_gps_follows_the_hills(tmp_path):
    """Inside the stop the poses freeze, the gyro reads 0 and the accelerometer gravity in the tilted base
    (a forward share of g sin(grade)); GPS altitudes follow the truth's height over the run."""
    out = tmp_path / "s.mcap"
    origin = (47.3769, 8.5417, 408.0)
    truth = _simulate(out, "rover", "--hills", "2:45", "--noise-scale", "0", "--stop", "9:3", "--start", "moving",
                      "--imu-rotation", "180,0,90", "--gps", "--gps-origin", ",".join(map(str, origin)),
                      "--duration", "20")
    assert truth["hills"]["amplitude_m"] == 2.0 and truth["hills"]["wavelength_m"] == 45.0
    assert truth["hills"]["max_grade"] == pytest.approx(2 * np.pi * 2 / 45)
    gt_ns, gt = read_tum(output_paths(out)[0])
    R_bi = np.asarray(truth["T_base_imu"])[:3, :3]
    lo, hi = START_NS + 9 * NS, START_NS + 12 * NS
    inside = (gt_ns >= lo) & (gt_ns <= hi)
    np.testing.assert_array_equal(gt[inside], np.broadcast_to(gt[inside][0], gt[inside].shape))
    R_wb = gt[inside][0][:3, :3]
    with open_log(out) as log:
        imu = [imu_sample(m) for _, _, _, m in log.messages(["/imu"])]
        fixes = [m for _, _, _, m in log.messages(["/gps/fix"]) if m.status.status == 0]
    rows = [s for s in imu if lo <= s[0] <= hi]
    gyro, accel = np.array([s[1] for s in rows]), np.array([s[2] for s in rows])
    assert len(rows) >= 600 and (gyro == 0.0).all()
    np.testing.assert_allclose(accel, np.broadcast_to(-GRAVITY_MPS2 @ R_wb @ R_bi, accel.shape), atol=1e-9)
    f_base = accel[0] @ R_bi.T
    assert f_base[0] < -2.0  # stopped going downhill: gravity has a forward share of 9.81 sin(grade)
    assert f_base[0] == pytest.approx(9.81 * R_wb[2, 0], abs=1e-7)  # the TUM file has 9 decimals
    # GPS altitude: the antenna's true height (noise 0; the ENU plane and the ellipsoid part by < 1 mm here)
    stamps = np.array([_stamp(m) for m in fixes])
    enu = EnuFrame(*origin).to_enu(np.array([m.latitude for m in fixes]), np.array([m.longitude for m in fixes]),
                                    np.array([m.altitude for m in fixes]))
    poses = gt[np.searchsorted(gt_ns, stamps)]
    assert (gt_ns[np.searchsorted(gt_ns, stamps)] == stamps).all()
    antenna = poses[:, :3, :3] @ np.asarray(truth["gps"]["T_base_gps"])[:3, 3] + poses[:, :3, 3]
    np.testing.assert_allclose(enu, antenna, atol=1e-3)
    assert np.ptp(enu[:, 2]) > 2.0


def test_true_motion_truth_and_metrics_record_the_hills(tmp_path):
    out = tmp_path / "t.mcap"
    truth = _simulate(out, "corridor", "--hills", "1.5:40", "--duration", "6", "--stop", "3:1", "--start", "moving")
    gt_ns, gt = read_tum(output_paths(out)[0])
    assert TrueMotion(output_paths(out)[1]).poses(gt_ns) == pytest.approx(gt, abs=1e-6)
    hills = truth["hills"]
    assert (hills["amplitude_m"], hills["wavelength_m"]) == (1.5, 40.0)
    assert hills["max_grade_deg"] == pytest.approx(np.degrees(np.arctan(2 * np.pi * 1.5 / 40)))
    assert "sqrt(1 + h'(s)^2)" in hills["meaning"] and truth["conditions"]["start"] == "moving"
    assert json.loads(metrics_path_for(out).read_text())["options"]["hills"] == [1.5, 40.0]


@pytest.mark.parametrize("scenario, argv, message", [
    ("drive", ("--hills", "2"), "--hills needs AMPLITUDE:WAVELENGTH, two numbers of metres such as 2:150 (got '2')"),
    ("drive", ("--hills", "2:150:3"),
     "--hills needs AMPLITUDE:WAVELENGTH, two numbers of metres such as 2:150 (got '2:150:3')"),
    ("drive", ("--hills", "a:b"), "--hills needs AMPLITUDE:WAVELENGTH, two numbers of metres such as 2:150 (got 'a:b')"),
    ("drive", ("--hills", "2:inf"),
     "--hills needs AMPLITUDE:WAVELENGTH, two numbers of metres such as 2:150 (got '2:inf')"),
    ("rover", ("--hills", "nan:150"),
     "--hills needs AMPLITUDE:WAVELENGTH, two numbers of metres such as 2:150 (got 'nan:150')"),
    ("drive", ("--no-lidar", "--hills", "-1:150"), "--hills -1:150: AMPLITUDE must be within 0..50 m"),
    ("drive", ("--no-lidar", "--hills", "51:5000"), "--hills 51:5000: AMPLITUDE must be within 0..50 m"),
    ("drive", ("--no-lidar", "--hills", "2:0"), "--hills 2:0: WAVELENGTH must be positive"),
    ("rover", ("--no-lidar", "--hills", "2:-100"), "--hills 2:-100: WAVELENGTH must be positive"),
    ("drive", ("--no-lidar", "--hills", "5:100"),  # ':100:' printed as typed, not as rich's emoji
     "--hills 5:100: the steepest grade, 2 pi AMPLITUDE / WAVELENGTH = 0.314 (17.4 deg), is more than wheels "
     "climb (0.3, 16.7 deg): make WAVELENGTH at least 105 m"),
    ("drive", ("--hills", "2:150"), "--hills needs --no-lidar: the simulated world's ground is flat, so a LiDAR "
                                    "would see the platform sink into it or float above it"),
    ("handheld", ("--no-lidar", "--hills", "2:150"), "--hills: the handheld scenario does not drive on the ground "
                                                     "(hills apply to drive, rover, corridor and planar)"),
    ("drone", ("--no-lidar", "--hills", "2:150"), "--hills: the drone scenario does not drive on the ground (hills "
                                                  "apply to drive, rover, corridor and planar)"),
    ("static", ("--hills", "2:150"), "--hills does not apply to the static scenario (an IMU at rest, no LiDAR, "
                                     "wheels or GPS)"),
])
def test_bad_hills_exit_2_with_one_line(tmp_path, capsys, monkeypatch, scenario, argv, message):
    assert_refused(tmp_path, capsys, monkeypatch, ["simulate", scenario, "x.mcap", "--duration", "20", *argv], message)
