"""``lio odom`` on logs it was not tuned for (issue 8): moving starts, any IMU mounting, misleading topics,
clocks that disagree, drivers that start in any order, real recordings.

Each accuracy threshold sits far below what the same run reaches LiDAR-only (asserted too), and far below
what the IMU-only start-up of the past gave (tens to hundreds of metres on these logs).
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from lio_cli.cli.app import main
from lio_cli.geometry import interpolate_poses
from lio_cli.io.logs.reader import open_log
from lio_cli.io.sensors.topics import choose_topic
from lio_cli.io.files.trajectory import read_tum
from lio_cli.io.logs.writer import LogWriter
from lio_cli.simulation.run import simulate

LIDAR_ONLY = ["--prior", "constant-velocity", "--deskew", "constant-velocity"]
# scenario -> ATE limit (m) for a moving start with the IMU upside down and yawed 90 deg
MOVING = {"handheld": 0.06, "drive": 0.10, "corridor": 0.15}


def _odom(log: Path, out: Path, *extra) -> tuple[int, dict | None]:
    rc = main(["odom", str(log), "-o", str(out), "-q", "--force", *map(str, extra)])
    metrics = out.with_name(out.stem + ".odom.metrics.json")
    return rc, json.loads(metrics.read_text()) if rc == 0 else None


def _sim(tmp_path_factory, name: str, scenario: str, duration_s: float = 6.0, **opts):
    root = tmp_path_factory.mktemp(name)
    return simulate(scenario, root / f"{name}.bag", "ros1", duration_s=duration_s, seed=1, columns=360, **opts)


@pytest.fixture(scope="module")
def moving_logs(tmp_path_factory):
    return {sc: _sim(tmp_path_factory, f"{sc}_moving", sc, start="moving", imu_rotation_deg=(180.0, 0.0, 90.0))
            for sc in MOVING}


@pytest.mark.parametrize("scenario", list(MOVING))
def test_moving_start_with_the_imu_upside_down(scenario, moving_logs, tmp_path):
    """Already moving at the first sample (the drive cruises so smoothly the IMU alone looks still): the start
    is found moving from LiDAR-only scans aligned with the IMU, at the right speed, and the run beats LiDAR-only."""
    res = moving_logs[scenario]
    rc, m = _odom(res.log_path, tmp_path / "lio.tum", "--gt", "/ground_truth")
    assert rc == 0
    start = m["start"]
    assert start["kind"] == "moving" and start["scans"] >= 10, start
    gt_stamps, gt_poses = read_tum(res.gt_path)
    t = start["stamp_ns"]
    k = int(np.searchsorted(gt_stamps, t))
    v_true = (gt_poses[k + 1, :3, 3] - gt_poses[k - 1, :3, 3]) / ((gt_stamps[k + 1] - gt_stamps[k - 1]) * 1e-9)
    assert start["speed_mps"] == pytest.approx(np.linalg.norm(v_true), rel=0.15, abs=0.1)
    ate = m["accuracy"]["ate_trans_rmse_m"]
    assert ate < MOVING[scenario], m["accuracy"]
    rc, lo = _odom(res.log_path, tmp_path / "lo.tum", "--gt", "/ground_truth", *LIDAR_ONLY)
    assert rc == 0 and ate < 0.5 * lo["accuracy"]["ate_trans_rmse_m"], (ate, lo["accuracy"])
    assert m["scans"]["recoveries"] == 0 and m["scans"]["lidar_only_scans"] == 0


def test_standing_start_is_confirmed_by_the_lidar(tmp_path_factory, tmp_path):
    res = _sim(tmp_path_factory, "still", "handheld", duration_s=4.0)
    rc, m = _odom(res.log_path, tmp_path / "o.tum")
    assert rc == 0
    assert m["start"]["kind"] == "standing" and m["start"]["speed_mps"] == 0.0
    assert m["start"]["reason"].startswith("standing start: LiDAR, IMU agree on no motion")


def test_first_scan_before_the_first_imu_message_still_uses_the_imu_extrinsic(tmp_path_factory, tmp_path):
    """The IMU driver starts 0.5 s late and the IMU is yawed 30 deg: its extrinsic is looked up by its frame_id
    when its first message arrives (identity was assumed before), and the clock offset is found online."""
    res = _sim(tmp_path_factory, "late_imu", "handheld", duration_s=8.0, imu_start_delay_s=0.5,
               imu_rotation_deg=(0.0, 0.0, 30.0))
    truth = json.loads(res.truth_path.read_text())
    assert truth["conditions"]["first_scan_before_first_imu"] is True
    rc, m = _odom(res.log_path, tmp_path / "o.tum", "--gt", "/ground_truth")
    assert rc == 0
    assert m["extrinsics"]["T_base_imu"] == "/tf_static (base -> imu)"
    assert m["notes"] == []
    assert m["accuracy"]["ate_trans_rmse_m"] < 0.06, m["accuracy"]
    # the scans before the IMU starts are LiDAR-only scans, not IMU gaps searched over yaw hypotheses
    assert m["scans"]["imu_gaps"] == 0 and not [e for e in m["events"] if e["kind"] == "imu gap"]


def test_an_imu_clock_offset_beyond_the_online_estimate_is_named_and_the_offset_given_fixes_it(tmp_path_factory,
                                                                                                tmp_path):
    """The IMU clock 40 ms off on a walk: the online estimate does not time it within 10 s (scans the IMU state
    cannot explain, placed by the LiDAR alone: 15 of them when each restarted the estimate, 5 now), and the walk
    ended 0.11 m off with no word. A warning names the disagreement and the fix; the offset given (as lio
    calibrate measures it: -40 ms here, the simulator's sign is the IMU's lag) takes the walk to 3 cm without a
    warning, and a log without an offset gets none."""
    res = _sim(tmp_path_factory, "clock40", "handheld", duration_s=10.0, imu_time_offset_s=-0.04)
    rc, m = _odom(res.log_path, tmp_path / "o.tum", "--gt", "/ground_truth")
    assert rc == 0
    n = m["scans"]["doubted_scans"]
    assert n >= 5 and m["accuracy"]["ate_trans_rmse_m"] > 0.08, (n, m["accuracy"])
    assert m["notes"] == [f"the IMU prediction and the registration disagreed on {n} of 100 scans (those were placed "
                          "by the LiDAR alone): an IMU clock offset of tens of ms or a wrong IMU extrinsic does this; "
                          "measure them with lio calibrate and give --imu-time-offset or --calib"]
    rc, fixed = _odom(res.log_path, tmp_path / "fixed.tum", "--gt", "/ground_truth", "--imu-time-offset", "-0.04")
    assert rc == 0 and fixed["scans"]["doubted_scans"] == 0 and fixed["notes"] == []
    assert fixed["accuracy"]["ate_trans_rmse_m"] < 0.04, fixed["accuracy"]
    plain = _sim(tmp_path_factory, "clock0", "handheld", duration_s=10.0)
    rc, m0 = _odom(plain.log_path, tmp_path / "plain.tum")
    assert rc == 0 and m0["scans"]["doubted_scans"] == 0 and m0["notes"] == []


def test_a_25_ms_imu_clock_offset_is_timed_through_the_scans_the_imu_state_doubts(tmp_path_factory, tmp_path):
    """The IMU clock 25 ms off on a 12 s walk: the scans the IMU state cannot explain are placed by the LiDAR
    alone, and their poses now time the clock too instead of restarting its window each time (which left the
    estimate at 5 ms and the walk 0.171 m off): 24 ms found, 5 cm."""
    res = simulate("handheld", tmp_path_factory.mktemp("clock25") / "clock25.bag", "ros1", duration_s=12.0, seed=5,
                   columns=360, imu_time_offset_s=0.025)
    rc, m = _odom(res.log_path, tmp_path / "o.tum", "--gt", "/ground_truth")
    assert rc == 0
    assert abs(m["imu_time_offset"]["estimated_s"] - 0.025) < 0.003, m["imu_time_offset"]
    assert m["accuracy"]["ate_trans_rmse_m"] < 0.06, m["accuracy"]
    assert 0 < m["scans"]["doubted_scans"] < 5 and m["notes"] == []


def test_a_40_ms_imu_clock_offset_is_timed_from_the_windows_the_imu_state_doubted(tmp_path_factory, tmp_path,
                                                                                   monkeypatch):
    """The IMU clock 40 ms off on a 15 s walk: the rounds over scans the IMU state doubted measure it less
    sharply (4-5 ms) than the 2 ms an ordinary round needs, and the disagreement is the evidence: applied at 5 ms,
    39 ms found and 5 cm; held to 2 ms, as before, it is not found."""
    import lio_cli.core.odometry.clock_offset as clock_offset

    res = simulate("handheld", tmp_path_factory.mktemp("clock40b") / "clock40b.bag", "ros1", duration_s=15.0,
                   seed=3, columns=360, imu_time_offset_s=0.04)
    rc, m = _odom(res.log_path, tmp_path / "o.tum", "--gt", "/ground_truth")
    assert rc == 0
    assert abs(m["imu_time_offset"]["estimated_s"] - 0.04) < 0.003, m["imu_time_offset"]
    assert m["accuracy"]["ate_trans_rmse_m"] < 0.07, m["accuracy"]
    monkeypatch.setattr(clock_offset, "APPLY_SIGMA_DOUBTED_S", clock_offset.APPLY_SIGMA_S)
    rc, held = _odom(res.log_path, tmp_path / "held.tum", "--gt", "/ground_truth")
    assert rc == 0 and abs(held["imu_time_offset"]["estimated_s"] - 0.04) > 0.01, held["imu_time_offset"]
    assert held["accuracy"]["ate_trans_rmse_m"] > 2 * m["accuracy"]["ate_trans_rmse_m"], held["accuracy"]


def test_an_imu_that_starts_seconds_late_is_named_with_the_lidar_only_scans_before_it(tmp_path_factory, tmp_path):
    """The IMU starts 3 s after the LiDAR (a walk 0.18 m / 21.6 deg off, where the scans before it lost a turn,
    with no word): a warning says how many scans had no rotation prior; a start within the start-up window
    (above, 0.5 s) gets none."""
    res = _sim(tmp_path_factory, "late_imu3", "handheld", duration_s=5.0, imu_start_delay_s=3.0)
    rc, m = _odom(res.log_path, tmp_path / "o.tum")
    assert rc == 0
    stamps, _ = read_tum(tmp_path / "o.tum")
    with open_log(res.log_path) as r:
        first_imu_ns = min(msg.stamp_ns for _, _, _, msg in r.messages(["/imu"], fast=True))
    before = int(np.sum(stamps < first_imu_ns))
    assert 29 <= before <= 31
    assert m["notes"] == [f"the IMU starts 3.0 s after the first scan: the {before} scans before its first sample are "
                          "LiDAR-only (no rotation prior; fast turns there are easily lost)"]


@pytest.fixture(scope="module")
def gt_odometry_log(tmp_path_factory):
    """A corridor with wheels and its ground truth as nav_msgs/Odometry with an all-zero twist."""
    return _sim(tmp_path_factory, "gt_odom", "corridor", duration_s=5.0, gt_type="odometry")


def test_ground_truth_odometry_is_never_taken_as_wheels(gt_odometry_log, tmp_path):
    rc, m = _odom(gt_odometry_log.log_path, tmp_path / "o.tum", "--gt", "/ground_truth")
    assert rc == 0
    roles = m["topic_roles"]
    assert roles["wheel"]["topic"] == "/wheel/odom"
    assert "/ground_truth: named as ground truth" in roles["wheel"]["why"]
    assert m["scans"]["wheel_updates"] > 0 and m["accuracy"]["ate_trans_rmse_m"] < 0.2


def test_an_odometry_topic_with_an_all_zero_twist_is_no_wheel_source(tmp_path_factory, tmp_path):
    """Ground truth published as /odom (not named so) with a zero twist, and no wheels: not taken as wheels."""
    res = _sim(tmp_path_factory, "odom_gt", "drive", duration_s=5.0, gt_type="odometry", gt_topic="/odom", wheel=False)
    rc, m = _odom(res.log_path, tmp_path / "o.tum", "--gt", "/odom")
    assert rc == 0
    assert m["topic_roles"]["wheel"]["topic"] is None
    assert "/odom: its twist is all zero over its first" in m["topic_roles"]["wheel"]["why"]
    assert m["accuracy"]["ate_trans_rmse_m"] < 0.15


def _tiny_log(path: Path, topics: dict[str, str], write) -> Path:
    with LogWriter(path, "ros1") as w:
        for topic, msgtype in topics.items():
            w.add_topic(topic, msgtype)
        write(w)
    return path


def _imu_rewritten(src: Path, dst: Path, edit) -> Path:
    """``src`` with every /imu message replaced by ``edit(stamp_ns, frame, gyro, accel)``'s (same four)."""
    def write(w):
        with open_log(src) as reader:
            for topic, _, t_ns, msg in reader.messages():
                if topic == "/imu":
                    g, a = msg.angular_velocity, msg.linear_acceleration
                    stamp = msg.header.stamp.sec * 10**9 + msg.header.stamp.nanosec
                    msg = w.make.imu(*edit(stamp, msg.header.frame_id, [g.x, g.y, g.z], [a.x, a.y, a.z]))
                w.write(topic, t_ns, msg)

    with open_log(src) as reader:
        topics = {t: i.msgtype for t, i in reader.topics.items()}
    return _tiny_log(dst, topics, write)


def test_an_imu_writing_g_is_read_in_m_per_s2(tmp_path):
    """Livox's IMU writes g: read as m/s^2 the walk came out 4 m off (a 15 s drive 19 m) with no word of it,
    the odometry "starting" at 4.4 m/s on a platform standing still."""
    res = simulate("handheld", tmp_path / "h.bag", "ros1", duration_s=6.0, seed=1, columns=360)
    log = _imu_rewritten(res.log_path, tmp_path / "g.bag",
                         lambda stamp, frame, g, a: (stamp, frame, g, [v / 9.80665 for v in a]))
    rc, m = _odom(log, tmp_path / "g.tum", "--gt", "/ground_truth")
    rc0, m0 = _odom(res.log_path, tmp_path / "ms2.tum", "--gt", "/ground_truth")
    assert rc == rc0 == 0
    assert m["start"]["kind"] == m0["start"]["kind"] == "standing"
    assert m["accuracy"]["ate_trans_rmse_m"] == pytest.approx(m0["accuracy"]["ate_trans_rmse_m"], abs=1e-3)
    assert m0["accuracy"]["ate_trans_rmse_m"] < 0.05
    assert "its accelerations are in g, not m/s^2" in m["topic_roles"]["imu"]["why"]
    assert "in g" not in m0["topic_roles"]["imu"]["why"]


def test_filter_outputs_and_zero_imus_are_not_taken_for_sensors(tmp_path):
    odom, imu = "nav_msgs/msg/Odometry", "sensor_msgs/msg/Imu"
    eye = np.eye(4)

    def write(w):
        for k in range(30):
            t = 10**9 + k * 20_000_000
            w.write("/odometry/filtered", t, w.make.odometry(t, "odom", "base_link", eye, [1.0, 0, 0], [0, 0, 0.1]))
            w.write("/jackal_velocity_controller/odom", t, w.make.odometry(t, "odom", "base_link", eye, [1.0, 0, 0],
                                                                           [0, 0, 0.1]))
            w.write("/vicon/base", t, w.make.odometry(t, "world", "base", eye, [1.0, 0, 0], [0, 0, 0.1]))
            w.write("/imu/zero", t, w.make.imu(t, "imu", [0.0, 0.0, 0.0], [0.0, 0.0, 0.0]))
            w.write("/imu/data", t, w.make.imu(t, "imu", [0.0, 0.0, 0.01], [0.0, 0.0, 9.81]))

    log = _tiny_log(tmp_path / "t.bag", {"/odometry/filtered": odom, "/jackal_velocity_controller/odom": odom,
                                         "/vicon/base": odom, "/imu/zero": imu, "/imu/data": imu}, write)
    with open_log(log) as reader:
        wheel = choose_topic(reader, "wheel")
        assert wheel.topic == "/jackal_velocity_controller/odom"
        assert "/odometry/filtered: named as another estimator's output" in wheel.why
        assert "/vicon/base: named as ground truth" in wheel.why
        imu_choice = choose_topic(reader, "imu")
        assert imu_choice.topic == "/imu/data" and "/imu/zero: its rates and accelerations are all zero" in imu_choice.why
        assert choose_topic(reader, "gt").topic == "/vicon/base"


def test_wheel_verdict_reads_until_the_twist_moves(tmp_path, monkeypatch):
    odom = "nav_msgs/msg/Odometry"
    eye = np.eye(4)

    def write(w):
        for k in range(30):
            t = 10**9 + k * 20_000_000
            v = 1.0 if k >= 5 else 0.0  # at rest over the first five messages
            w.write("/wheel/odom", t, w.make.odometry(t, "odom", "base_link", eye, [v, 0, 0], [0, 0, 0]))
            w.write("/pose/odom", t, w.make.odometry(t, "odom", "base_link", eye, [0, 0, 0], [0, 0, 0]))

    log = _tiny_log(tmp_path / "w.bag", {"/wheel/odom": odom, "/pose/odom": odom}, write)
    with open_log(log) as reader:
        read: list[str] = []
        original = reader.records

        def records(topics):
            for rec in original(topics):
                read.append(rec.connection.topic)
                yield rec

        monkeypatch.setattr(reader, "records", records)
        choice = choose_topic(reader, "wheel")
    assert choice.topic == "/wheel/odom"
    assert "/pose/odom: its twist is all zero over its first 30 messages (a pose source)" in choice.why
    assert len(read) == 6 + 30  # /wheel/odom read up to its first moving message, /pose/odom all through


def test_an_imu_topic_of_zeros_is_refused(tmp_path, capsys):
    res = simulate("handheld", tmp_path / "h.bag", "ros1", duration_s=2.0, seed=1, columns=180)

    log = _imu_rewritten(res.log_path, tmp_path / "zero.bag", lambda stamp, frame, g, a: (stamp, frame, [0, 0, 0], [0, 0, 0]))
    rc, _ = _odom(log, tmp_path / "o.tum")
    assert rc == 2
    assert capsys.readouterr().err.strip() == (
        f"lio: error: {log}: IMU topic /imu carries only zeros (rates and accelerations): not an IMU; run LiDAR-only "
        "with --prior constant-velocity --deskew constant-velocity")


def test_sensors_on_different_clocks_stop_with_the_option_that_fixes_it(tmp_path, capsys):
    """The IMU stamped on its uptime (as the real Ouster's), the clouds on epoch time."""
    res = simulate("handheld", tmp_path / "h.bag", "ros1", duration_s=4.0, seed=1, columns=180)
    uptime_shift_ns = -(1_700_000_000 - 1622) * 10**9

    log = _imu_rewritten(res.log_path, tmp_path / "clocks.bag",
                         lambda stamp, frame, g, a: (stamp + uptime_shift_ns, frame, g, a))
    rc, _ = _odom(log, tmp_path / "o.tum")
    assert rc == 2
    err = capsys.readouterr().err.strip()
    assert err.startswith(f"lio: error: {log}: /imu and /points are stamped on different clocks (/imu from 1622.")
    suggested = float(err.rsplit("if /imu runs on a shifted clock give --imu-time-offset ", 1)[1])
    assert suggested == pytest.approx(-uptime_shift_ns / 1e9, abs=0.2)  # from recording times: a hint, not exact
    assert "\n" not in err and not (tmp_path / "o.tum").exists()
    rc, m = _odom(log, tmp_path / "o.tum", "--imu-time-offset", -uptime_shift_ns / 1e9, "--gt", "/ground_truth")
    assert rc == 0 and m["accuracy"]["ate_trans_rmse_m"] < 0.05


def test_a_driver_tree_without_a_base_frame_gives_the_mounting(tmp_path):
    """/tf_static as Ouster's driver writes it: os_sensor -> lidar, os_sensor -> imu, no base_link/base/
    base_footprint. Both extrinsics were taken as identity (with the IMU turned 180 deg: a walk 0.35 m off and
    its de-skew 65 mm); the tree's root is the base now."""
    from lio_cli.io.messages.decode import decode_tf

    res = simulate("handheld", tmp_path / "h.bag", "ros1", duration_s=8.0, seed=1, columns=360,
                   imu_rotation_deg=(0.0, 0.0, 180.0))

    def renamed(w):
        with open_log(res.log_path) as reader:
            for topic, _, t_ns, msg in reader.messages():
                if topic == "/tf_static":
                    msg = w.make.tf_message([w.make.transform_stamped(tr.stamp_ns, "os_sensor", tr.child, tr.pose)
                                             for tr in decode_tf(msg)])
                w.write(topic, t_ns, msg)

    with open_log(res.log_path) as reader:
        topics = {t: i.msgtype for t, i in reader.topics.items()}
    log = _tiny_log(tmp_path / "os.bag", topics, renamed)
    rc, m = _odom(log, tmp_path / "os.tum", "--gt", "/ground_truth")
    assert rc == 0 and m["accuracy"]["ate_trans_rmse_m"] < 0.06
    assert m["extrinsics"] == {"base_frame": "os_sensor", "T_base_imu": "/tf_static (os_sensor -> imu)",
                               "T_base_lidar": "/tf_static (os_sensor -> lidar)"}
    assert "base frame 'os_sensor': the root of /tf_static's tree holding 'lidar' (none is named base_link, base, " \
           "base_footprint; --base-frame chooses another)" in m["notes"]


def test_clouds_recorded_late_are_not_a_clock_mismatch(tmp_path):
    """Large clouds queued 0.6 s behind their stamps while the IMU's messages were recorded at once: both on one
    clock (their first stamps agree), which the check once refused as "0.6 s apart beyond their recording
    times", advising --imu-time-offset -0.600 (ATE 1.29 m when followed)."""
    res = simulate("handheld", tmp_path / "h.bag", "ros1", duration_s=4.0, seed=1, columns=180)

    def late_clouds(w):
        with open_log(res.log_path) as reader:
            for topic, _, t_ns, msg in reader.messages():
                w.write(topic, t_ns + (600_000_000 if topic == "/points" else 0), msg)

    with open_log(res.log_path) as reader:
        topics = {t: i.msgtype for t, i in reader.topics.items()}
    log = _tiny_log(tmp_path / "late.bag", topics, late_clouds)
    rc, m = _odom(log, tmp_path / "late.tum", "--gt", "/ground_truth")
    rc0, m0 = _odom(res.log_path, tmp_path / "o.tum", "--gt", "/ground_truth")
    assert rc == rc0 == 0
    assert m["accuracy"]["ate_trans_rmse_m"] == pytest.approx(m0["accuracy"]["ate_trans_rmse_m"], rel=1e-9)
    assert m0["accuracy"]["ate_trans_rmse_m"] < 0.05


def test_a_track_lost_for_good_exits_1_and_keeps_the_trajectory_up_to_there(tmp_path, capsys):
    """Every scan after 2 s shows another world: no registration can place them; after max_lost_scans the
    run stops with exit 1 naming the scan and stamp, and the poses before it are written."""
    res = simulate("handheld", tmp_path / "h.bag", "ros1", duration_s=5.0, seed=2, columns=180)
    rng = np.random.default_rng(0)
    from lio_cli.io.messages.pointcloud import cloud_dtype

    def garbage_after_2s(w):
        with open_log(res.log_path) as reader:
            t_first = None
            for topic, _, t_ns, msg in reader.messages():
                if topic == "/points":
                    t_first = t_first or t_ns
                    if t_ns - t_first > 2 * 10**9:
                        arr = np.frombuffer(np.asarray(msg.data, dtype=np.uint8).tobytes(), dtype=cloud_dtype(msg)).copy()
                        arr = arr[:3000]
                        arr["x"], arr["y"] = rng.uniform(-30, 30, (2, len(arr)))  # nothing of the building:
                        arr["z"] = rng.uniform(20, 30, len(arr))  # a cloud high above it
                        stamp = msg.header.stamp.sec * 10**9 + msg.header.stamp.nanosec
                        msg = w.make.pointcloud2(stamp, msg.header.frame_id, arr)
                w.write(topic, t_ns, msg)

    with open_log(res.log_path) as reader:
        topics = {t: i.msgtype for t, i in reader.topics.items()}
    log = _tiny_log(tmp_path / "lost.bag", topics, garbage_after_2s)
    out = tmp_path / "o.tum"
    rc = main(["odom", str(log), "-o", str(out), "-q", "--config", str(_config(tmp_path, max_lost_scans=5))])
    assert rc == 1
    err = capsys.readouterr().err.strip()
    assert "lost track at scan" in err and "could place 5 scans in a row" in err
    assert err.endswith(f"the trajectory up to there is in {out}") and "\n" not in err
    stamps, _ = read_tum(out)
    assert 20 <= len(stamps) <= 30  # the scans of the first 2 s and the few after them


def _config(tmp_path: Path, **fields) -> Path:
    path = tmp_path / "c.yaml"
    path.write_text("".join(f"{k}: {v}\n" for k, v in fields.items()))
    return path


# ---- real recordings ------------------------------------------------------------------------------------


def test_real_velodyne_with_two_scans_and_no_extrinsics(real_logs, tmp_path, capsys):
    rc, m = _odom(real_logs / "s3e_playground_2", tmp_path / "s3e.tum")
    assert rc == 0
    assert m["scans"]["used"] == 2 and m["start"]["kind"] == "lidar-only"  # far shorter than the start-up window
    assert m["extrinsics"]["T_base_imu"] == "identity (assumed)"
    assert "no extrinsic T_base_imu (base -> imu_link)" in capsys.readouterr().err


def test_real_ouster_imu_on_another_clock_is_refused_then_runs_with_the_offset(real_logs, tmp_path, capsys):
    log = real_logs / "ouster_os1_ros1_mcap" / "os1_64.mcap"
    rc, _ = _odom(log, tmp_path / "os1.tum")
    assert rc == 2
    err = capsys.readouterr().err.strip()
    assert "/os1_cloud_node/imu and /os1_cloud_node/points are stamped on different clocks" in err
    offset = err.rsplit("--imu-time-offset ", 1)[1]
    rc, m = _odom(log, tmp_path / "os1.tum", "--imu-time-offset", offset)
    assert rc == 0 and m["scans"]["used"] == 2
    assert m["extrinsics"]["T_base_lidar"].startswith("/tf_static") or m["extrinsics"]["T_base_lidar"] == "identity (assumed)"


def test_real_luminar_truck_needs_its_lidar_topic_and_never_takes_the_unrelated_ground_truth(real_logs, tmp_path):
    log = real_logs / "luminar_truck" / "luminar.bag"
    rc, m = _odom(log, tmp_path / "lum.tum", "--lidar-topic", "/luminar_pointcloud", *LIDAR_ONLY)
    assert rc == 0
    assert m["topic_roles"]["wheel"]["topic"] is None
    assert "/base_pose_ground_truth: named as ground truth" in m["topic_roles"]["wheel"]["why"]
    stamps, poses = read_tum(tmp_path / "lum.tum")
    assert len(stamps) == 5
    # a truck at ~23 m/s: four scan intervals of ~90 ms move it about 8 m along the road
    assert 5.0 < np.linalg.norm(poses[-1, :3, 3] - poses[0, :3, 3]) < 12.0
    assert interpolate_poses(stamps, poses, stamps[:1]).shape == (1, 4, 4)
