"""`lio simulate` end to end: every scenario in every format read back by `lio info` and rosbags' AnyReader
(topics, counts, rates), per-point time conventions, ground truth file and topic, truth JSON, same seed
same bytes, overwrite refusal."""

from __future__ import annotations

import hashlib
import json
from pathlib import Path

import numpy as np
import pytest

from lio_cli.cli.app import main
from lio_cli.geometry import so3_log
from lio_cli.io.messages.decode import decode_pose, decode_tf
from lio_cli.io.logs.reader import open_log
from lio_cli.io.messages.pointcloud import decode_pointcloud2, decode_laserscan
from lio_cli.io.files.trajectory import read_tum
from lio_cli.simulation import SCENARIOS, build_scenario, output_paths, simulate

NS = 1_000_000_000
START_NS = 1_700_000_000 * NS
DURATION_S = 2.0
SUFFIX = {"ros1": ".bag", "ros2": "", "mcap": ".mcap"}
RATE_RTOL = 1e-6  # stamps are exact integer ns on a regular grid
TINY = {"columns": 64}  # keep test logs small and fast

# expected (type, count in DURATION_S) by topic; wheel odometry only for wheeled platforms
EXPECTED = {
    "/tf_static": ("tf2_msgs/msg/TFMessage", 1),
    "/imu": ("sensor_msgs/msg/Imu", int(DURATION_S * 200) + 1),
    "/ground_truth": ("geometry_msgs/msg/PoseStamped", int(DURATION_S * 100) + 1),
    "/wheel/odom": ("nav_msgs/msg/Odometry", int(DURATION_S * 50) + 1),
    "/points": ("sensor_msgs/msg/PointCloud2", int(DURATION_S * 10)),
    "/scan": ("sensor_msgs/msg/LaserScan", int(DURATION_S * 10)),
}
RATES_HZ = {"/imu": 200.0, "/ground_truth": 100.0, "/wheel/odom": 50.0, "/points": 10.0, "/scan": 10.0}


def expected_topics(scenario: str) -> set[str]:
    topics = {"/tf_static", "/imu", "/ground_truth", "/scan" if scenario == "planar" else "/points"}
    if scenario not in ("handheld", "drone"):
        topics.add("/wheel/odom")
    return topics


def run(capsys, *argv) -> tuple[int, str, str]:
    rc = main([str(a) for a in argv])
    out, err = capsys.readouterr()
    return rc, out, err


@pytest.mark.parametrize("fmt", ["ros1", "ros2", "mcap"])
@pytest.mark.parametrize("scenario", SCENARIOS)
def test_every_scenario_and_format_reads_back(tmp_path, capsys, scenario, fmt):
    out = tmp_path / f"{scenario}{SUFFIX[fmt]}"
    rc, stdout, err = run(capsys, "simulate", scenario, out, "--format", fmt, "--duration", DURATION_S,
                          "--columns", 64 if scenario != "planar" else 180, "--json", "--seed", 5)
    assert rc == 0, err
    summary = json.loads(stdout)
    assert summary["format"] == fmt and summary["log_path"] == str(out)
    want = expected_topics(scenario)
    assert set(summary["topics"]) == want

    # lio info: topics, types, counts; IMU and ground truth rates are exact over the log span
    rc, stdout, err = run(capsys, "info", out, "--json")
    assert rc == 0, err
    info = json.loads(stdout)
    assert info["format"] == fmt
    assert info["start_ns"] == START_NS
    got = {t["topic"]: (t["type"], t["count"]) for t in info["topics"]}
    assert got == {t: EXPECTED[t] for t in want}
    rates = {t["topic"]: t["rate_hz"] for t in info["topics"]}
    np.testing.assert_allclose(rates["/imu"], 200.0, rtol=RATE_RTOL)
    np.testing.assert_allclose(rates["/ground_truth"], 100.0, rtol=RATE_RTOL)
    frames = {(f["parent"], f["child"]) for f in info["static_transforms"]}
    assert frames == {("base", "imu"), ("base", "lidar")}
    scan = info["scans"][0]
    assert scan["frame_id"] == "lidar"
    if scenario != "planar":
        assert scan["time_convention"]["name"] == "velodyne"
        assert scan["time_convention"]["header_stamp_marks"] == "start"

    # rosbags' AnyReader (reads ROS 1, ROS 2 and bare MCAP): counts and per-topic rates from record times
    from rosbags.highlevel import AnyReader

    with AnyReader([out]) as reader:
        stamps: dict[str, list[int]] = {}
        for conn, t_ns, _ in reader.messages():
            stamps.setdefault(conn.topic, []).append(t_ns)
        assert {c.topic: c.msgtype for c in reader.connections} == {t: EXPECTED[t][0] for t in want}
    assert {t: len(v) for t, v in stamps.items()} == {t: EXPECTED[t][1] for t in want}
    for topic, hz in RATES_HZ.items():
        if topic in stamps:
            s = np.asarray(stamps[topic])
            np.testing.assert_allclose((len(s) - 1) / ((s[-1] - s[0]) * 1e-9), hz, rtol=RATE_RTOL)


@pytest.mark.parametrize("convention", ["velodyne", "ouster", "livox", "hesai"])
def test_time_conventions_decode_to_the_same_point_stamps(tmp_path, convention):
    out = tmp_path / f"{convention}.mcap"
    simulate("handheld", out, duration_s=0.35, seed=1, time_convention=convention, **TINY)
    with open_log(out) as log:
        msgs = [(t, m) for _, _, t, m in log.messages(["/points"])]
    assert len(msgs) == 3
    for k, (record_ns, msg) in enumerate(msgs):
        cloud = decode_pointcloud2(msg)  # convention detected from the fields
        start = START_NS + k * 100_000_000
        assert cloud.convention.name == convention
        assert cloud.stamp_ns == start and record_ns == start + 100_000_000  # header = start, record = end
        assert cloud.header_marks == "start"
        expected_offsets = (np.arange(64, dtype=np.int64) * 100_000_000) // 64
        tol_ns = 1000 if convention == "hesai" else 10  # float64 absolute seconds keep ~0.2 us
        offsets = cloud.point_stamps_ns - start
        assert np.all(np.min(np.abs(offsets[:, None] - expected_offsets[None, :]), axis=1) <= tol_ns)
        assert len(np.unique(offsets // 1_000_000)) > 50  # spread over the whole sweep


def test_ground_truth_file_topic_and_truth_json_agree(tmp_path):
    out = tmp_path / "c.bag"
    res = simulate("corridor", out, duration_s=DURATION_S, seed=2, imu_time_offset_s=-0.004, **TINY)
    gt_path, truth_path = output_paths(out)
    assert (res.gt_path, res.truth_path) == (gt_path, truth_path) == (tmp_path / "c.gt.tum", tmp_path / "c.truth.json")
    stamps, poses = read_tum(gt_path)
    np.testing.assert_array_equal(stamps, START_NS + np.arange(201, dtype=np.int64) * 10_000_000)
    line = gt_path.read_text().splitlines()[1]
    assert line.split()[0] == "1700000000.010000000"  # exact ns, not through a float
    sc = build_scenario("corridor")
    np.testing.assert_allclose(poses, sc.trajectory.poses((stamps - START_NS) * 1e-9), atol=1e-8)
    truth = json.loads(truth_path.read_text())
    np.testing.assert_allclose(truth["T_base_imu"], sc.T_base_imu, atol=1e-12)
    np.testing.assert_allclose(truth["T_base_lidar"], sc.T_base_lidar, atol=1e-12)
    assert truth["imu"]["imu_time_offset_ns"] == -4_000_000 and truth["seed"] == 2 and truth["scenario"] == "corridor"
    assert np.linalg.norm(truth["imu"]["accel_bias_mps2"]) > 0 and np.linalg.norm(truth["imu"]["gyro_bias_radps"]) > 0
    assert truth["wheel"]["slip"]["left"] > 0 and truth["wheel"]["baseline_scale"] != 1.0
    with open_log(out) as log:
        gt_msgs = [decode_pose(m, mt) for _, mt, _, m in log.messages(["/ground_truth"])]
        tf = [tr for _, _, _, m in log.messages(["/tf_static"]) for tr in decode_tf(m)]
        imu_stamps = [m.header.stamp.sec * NS + m.header.stamp.nanosec for _, _, _, m in log.messages(["/imu"])]
    assert [g.stamp_ns for g in gt_msgs] == stamps.tolist()
    assert all(g.frame_id == "world" for g in gt_msgs)
    np.testing.assert_allclose(np.stack([g.pose for g in gt_msgs]), poses, atol=1e-8)
    by_child = {t.child: t for t in tf}
    np.testing.assert_allclose(by_child["imu"].pose, sc.T_base_imu, atol=1e-9)
    assert np.degrees(np.linalg.norm(so3_log(by_child["imu"].pose[:3, :3]))) > 45  # a real rotation
    assert by_child["lidar"].parent == "base" and by_child["lidar"].stamp_ns == START_NS
    assert imu_stamps[0] == START_NS and imu_stamps[1] - imu_stamps[0] == 5_000_000


def test_planar_laserscan_and_wheel_odometry_content(tmp_path):
    out = tmp_path / "p.mcap"
    simulate("planar", out, duration_s=DURATION_S, seed=0, noise_scale=0.0)
    sc = build_scenario("planar")
    with open_log(out) as log:
        scans = [m for _, _, _, m in log.messages(["/scan"])]
        odom = [m for _, _, _, m in log.messages(["/wheel/odom"])]
    cloud = decode_laserscan(scans[5])
    assert cloud.frame_id == "lidar" and len(scans[5].ranges) == 720
    assert cloud.stamp_ns == START_NS + 5 * 100_000_000 and cloud.end_ns < cloud.stamp_ns + 100_000_000
    assert len(cloud.points) == 720  # noise off: no dropouts, walls everywhere within 30 m
    assert odom[0].header.frame_id == "odom" and odom[0].child_frame_id == "base"
    last = odom[-1]
    t_last = (last.header.stamp.sec * NS + last.header.stamp.nanosec - START_NS) * 1e-9
    T0, T1 = sc.trajectory.poses(np.array([0.0, t_last]))
    rel = np.linalg.inv(T0) @ T1
    p = last.pose.pose.position
    np.testing.assert_allclose([p.x, p.y], rel[:2, 3], atol=1e-4)
    speed = np.linalg.norm(sc.trajectory.state(np.array([t_last])).velocity_mps)
    assert last.twist.twist.linear.x == pytest.approx(speed, abs=1e-9)


def _digest(path: Path) -> str:
    h = hashlib.sha256()
    files = sorted(p for p in path.rglob("*") if p.is_file()) if path.is_dir() else [path]
    for f in files:
        h.update(f.name.encode())
        h.update(f.read_bytes())
    return h.hexdigest()


@pytest.mark.parametrize("fmt", ["ros1", "ros2", "mcap"])
def test_same_seed_same_bytes(tmp_path, fmt):
    digests = []
    for run_dir in ("a", "b", "c"):
        (tmp_path / run_dir).mkdir()
        out = tmp_path / run_dir / f"log{SUFFIX[fmt]}"
        seed = 9 if run_dir != "c" else 10
        simulate("corridor", out, fmt, duration_s=0.5, seed=seed, **TINY)
        gt, truth = output_paths(out)
        digests.append((_digest(out), _digest(gt), _digest(truth)))
    assert digests[0] == digests[1]
    assert digests[2][0] != digests[0][0]  # another seed, other noise


def test_refuses_to_overwrite_without_force(tmp_path, capsys):
    out = tmp_path / "h.mcap"
    args = ("simulate", "handheld", out, "--duration", 0.3, "--columns", 32, "--quiet")
    assert run(capsys, *args)[0] == 0
    before = out.read_bytes()
    rc, stdout, err = run(capsys, *args)
    assert rc == 2 and stdout == ""
    assert err == f"lio: error: {out}: already exists; pass --force to overwrite it\n"
    assert out.read_bytes() == before
    # the ground-truth file alone also blocks (nothing half-written)
    out2 = tmp_path / "h2.bag"
    (tmp_path / "h2.gt.tum").write_text("keep\n")
    rc, _, err = run(capsys, "simulate", "handheld", out2, "--duration", 0.3, "--columns", 32)
    assert rc == 2 and err == f"lio: error: {tmp_path / 'h2.gt.tum'}: already exists; pass --force to overwrite it\n"
    assert not out2.exists() and (tmp_path / "h2.gt.tum").read_text() == "keep\n"
    rc, _, err = run(capsys, *args, "--force", "--seed", 4)
    assert rc == 0, err
    assert out.read_bytes() != before


@pytest.mark.parametrize("argv, message", [
    (("simulate", "flying", "x.bag"), "lio: error: Invalid value for 'SCENARIO': 'flying' is not one of 'handheld', "
     "'drive', 'corridor', 'planar', 'rover', 'drone', 'static'; see 'lio simulate --help'\n"),
    (("simulate", "handheld", "x.bag", "--time-convention", "sick"),
     "lio: error: Invalid value for '--time-convention': 'sick' is not one of 'velodyne', 'ouster', 'livox', "
     "'hesai'; see 'lio simulate --help'\n"),
    (("simulate", "handheld", "x.bag", "--beams", "24"), "lio: error: --beams must be 16, 32, 64 or 128 (got 24)\n"),
    (("simulate", "handheld", "x.bag", "--duration", "0"), "lio: error: --duration must be positive (got 0.0)\n"),
    (("simulate", "handheld", "x.bag", "--range-noise", "-0.1"), "lio: error: --range-noise must be >= 0 m (got -0.1)\n"),
    (("simulate", "handheld", "x.bag", "--imu-rate", "5"), "lio: error: --imu-rate must be between 10 and 2000 Hz (got 5.0)\n"),
    (("simulate", "handheld", "x.bag", "--format", "rosbag"),
     "lio: error: Invalid value for '--format': 'rosbag' is not one of 'ros1', 'ros2', 'ros2-mcap', 'mcap'; "
     "see 'lio simulate --help'\n"),
])
def test_bad_arguments_exit_2_with_one_line(tmp_path, capsys, monkeypatch, argv, message):
    monkeypatch.chdir(tmp_path)
    rc, stdout, err = run(capsys, *argv)
    assert (rc, stdout, err) == (2, "", message)
    assert not any(tmp_path.iterdir())


def test_noise_scale_zero_gives_ideal_sensors(tmp_path):
    out = tmp_path / "ideal.mcap"
    simulate("handheld", out, duration_s=0.5, seed=0, noise_scale=0.0, **TINY)
    truth = json.loads(output_paths(out)[1].read_text())
    assert truth["imu"]["accel_bias_mps2"] == [0.0, 0.0, 0.0] and truth["lidar"]["range_noise_m"] == 0.0
    with open_log(out) as log:
        imu = [m for _, _, _, m in log.messages(["/imu"])]
    a = imu[0].linear_acceleration
    sc = build_scenario("handheld")
    np.testing.assert_allclose([a.x, a.y, a.z], sc.T_base_imu[:3, :3].T @ [0.0, 0.0, 9.81], atol=1e-9)


def test_progress_reports_simulated_seconds(tmp_path):
    seen: list[float] = []
    simulate("planar", tmp_path / "p.bag", duration_s=1.0, seed=0, progress=seen.append)
    assert len(seen) == 10
    assert sum(seen) == pytest.approx(1.0)


SAMPLE_LOGS = Path(__file__).resolve().parents[2] / "sample_logs"
SAMPLE_BUDGET_BYTES = 20_000_000


def test_sample_logs_are_small_and_hold_what_the_readme_says():
    files = [p for p in SAMPLE_LOGS.rglob("*") if p.is_file()]
    assert sum(p.stat().st_size for p in files) <= SAMPLE_BUDGET_BYTES
    readme = (SAMPLE_LOGS / "README.md").read_text()
    for name, fmt, scenario, duration_s, lidar in [("handheld.bag", "ros1", "handheld", 7, "/points"),
                                                    ("corridor_ros2", "ros2", "corridor", 6, "/points"),
                                                    ("planar.mcap", "mcap", "planar", 15, "/scan")]:
        log = SAMPLE_LOGS / name
        assert f"lio simulate {scenario} sample_logs/{name.rstrip('/')}" in readme
        with open_log(log) as reader:
            assert reader.format == fmt
            assert set(reader.topics) == expected_topics(scenario)
            assert reader.topics[lidar].count == duration_s * 10
            assert reader.topics["/imu"].count == duration_s * 200 + 1
        gt, truth = output_paths(log)
        stamps, poses = read_tum(gt)
        assert len(stamps) == duration_s * 100 + 1
        # the ground truth is the scenario's trajectory (no randomness in it)
        sc = build_scenario(scenario)
        np.testing.assert_allclose(poses, sc.trajectory.poses((stamps - START_NS) * 1e-9), atol=1e-8)
        assert json.loads(truth.read_text())["scenario"] == scenario


def test_cli_options_reach_the_log(tmp_path, capsys):
    out = tmp_path / "town"
    rc, _, err = run(capsys, "simulate", "drive", out, "--format", "ros2-mcap", "--duration", 0.5, "--beams", 64,
                     "--columns", 32, "--imu-rate", 400, "--imu-time-offset", 0.003, "--time-convention", "ouster",
                     "--range-noise", 0.0, "--dropout", 0.0, "--seed", 3, "--quiet")
    assert rc == 0, err
    assert err == ""  # --quiet: nothing on stderr
    assert (out / "town.mcap").is_file()
    with open_log(out) as log:
        assert log.format == "ros2"
        assert log.topics["/imu"].count == 201
        clouds = [m for _, _, _, m in log.messages(["/points"])]
        imu = [m for _, _, _, m in log.messages(["/imu"])]
    assert len(clouds) == 5
    cloud = decode_pointcloud2(clouds[2])
    assert cloud.convention.name == "ouster"
    assert 0.5 * 64 * 32 < len(cloud.points) <= 64 * 32  # no dropouts: every ray that hits within range
    from lio_cli.io.messages.pointcloud import cloud_dtype

    rings = np.frombuffer(bytes(clouds[2].data), dtype=cloud_dtype(clouds[2]))["ring"]
    assert rings.max() == 63
    truth = json.loads((tmp_path / "town.truth.json").read_text())
    assert truth["imu"]["imu_time_offset_ns"] == 3_000_000 and truth["imu"]["rate_hz"] == 400.0
    assert truth["lidar"]["beams"] == 64 and truth["lidar"]["time_convention"] == "ouster"
    assert truth["lidar"]["range_noise_m"] == 0.0
    stamps = [m.header.stamp.sec * NS + m.header.stamp.nanosec for m in imu]
    assert stamps[0] == START_NS and stamps[1] - stamps[0] == 2_500_000


@pytest.mark.parametrize("convention", ["velodyne", "hesai"])
def test_header_stamp_at_sweep_end_keeps_every_point_stamp(tmp_path, convention):
    points = {}
    for mark in ("start", "end"):
        out = tmp_path / f"{mark}.bag"
        simulate("handheld", out, duration_s=0.25, seed=1, time_convention=convention, header_stamp=mark, **TINY)
        with open_log(out) as log:
            msgs = [(t, m) for _, _, t, m in log.messages(["/points"])]
        clouds = [decode_pointcloud2(m) for _, m in msgs]
        assert [c.header_marks for c in clouds] == [mark, mark]
        assert [c.stamp_ns for c in clouds] == [START_NS + k * 100_000_000 + (mark == "end") * 100_000_000 for k in (0, 1)]
        assert [t for t, _ in msgs] == [START_NS + 100_000_000, START_NS + 200_000_000]  # recorded at the end
        points[mark] = clouds
    for a, b in zip(points["start"], points["end"]):
        tol_ns = 1000 if convention == "hesai" else 10
        np.testing.assert_allclose(a.point_stamps_ns - START_NS, b.point_stamps_ns - START_NS, atol=tol_ns)
        np.testing.assert_array_equal(a.points, b.points)


def test_header_stamp_end_refused_for_unsigned_offsets(tmp_path, capsys):
    rc, _, err = run(capsys, "simulate", "handheld", tmp_path / "x.bag", "--time-convention", "livox",
                     "--header-stamp", "end")
    assert rc == 2
    assert err == ("lio: error: --header-stamp end needs negative per-point offsets, which the livox convention "
                   "(unsigned ns) cannot hold; use --time-convention velodyne or hesai\n")
