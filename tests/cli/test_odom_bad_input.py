"""``lio odom`` on damaged logs: every defect is handled, counted in metrics, or refused with one line."""

import json

import numpy as np
import pytest

from lio_cli.cli.app import main
from lio_cli.io.logs.reader import open_log
from lio_cli.io.messages.pointcloud import cloud_dtype
from lio_cli.io.logs.writer import LogWriter
from lio_cli.simulation.run import simulate

SCAN_TOPIC = "/points"


@pytest.fixture(scope="module")
def base_log(tmp_path_factory):
    root = tmp_path_factory.mktemp("base")
    return simulate("handheld", root / "h.bag", "ros1", duration_s=4.0, seed=2, columns=180).log_path


def copy_log(src, dst, edit=None):
    """Copy a ROS 1 log; ``edit(topic, t_ns, msg, writer)`` returns a list of (topic, t_ns, msg) to write."""
    with open_log(src) as reader, LogWriter(dst, "ros1") as w:
        for topic, info in reader.topics.items():
            w.add_topic(topic, info.msgtype)
        for topic, msgtype, t_ns, msg in reader.messages():
            out = [(topic, t_ns, msg)] if edit is None else edit(topic, t_ns, msg, w)
            for tp, t, m in out:
                w.write(tp, t, m)
    return dst


def _cloud(msg, w, keep=None, nan_rows=None, replace_xyz=None):
    arr = np.frombuffer(np.asarray(msg.data, dtype=np.uint8).tobytes(), dtype=cloud_dtype(msg)).copy()
    if replace_xyz is not None:
        arr = arr[: len(replace_xyz)]
        arr["x"], arr["y"], arr["z"] = replace_xyz.T
    if nan_rows is not None:
        arr["x"][nan_rows] = np.nan
    if keep is not None:
        arr = arr[:keep]
    stamp_ns = msg.header.stamp.sec * 10**9 + msg.header.stamp.nanosec
    return w.make.pointcloud2(stamp_ns, msg.header.frame_id, arr)


def _odom(log, tmp_path, *extra):
    out = tmp_path / "o.tum"
    rc = main(["odom", str(log), "-o", str(out), "-q", *extra])
    metrics = json.loads((tmp_path / "o.odom.metrics.json").read_text()) if rc == 0 else None
    return rc, metrics


def test_no_imu_topic_says_so_and_suggests_constant_velocity(base_log, tmp_path, capsys):
    log = copy_log(base_log, tmp_path / "noimu.bag", lambda tp, t, m, w: [] if tp == "/imu" else [(tp, t, m)])
    rc, _ = _odom(log, tmp_path)
    assert rc == 2
    err = capsys.readouterr().err.strip()
    # the copy declares /imu and writes none of its messages: the line names it
    assert err == (f"lio: error: {log}: no IMU topic (sensor_msgs/Imu) (/imu is declared but never published) for "
                   "--prior imu; run LiDAR-only with "
                   "--prior constant-velocity --deskew constant-velocity, or name the topic with --imu-topic")
    rc, metrics = _odom(log, tmp_path, "--prior", "constant-velocity")
    assert rc == 0
    assert metrics["fusion"] == "none (no IMU)"
    assert metrics["extrinsics"]["T_base_imu"] == "not used (no IMU in this run)"
    assert "warning" not in capsys.readouterr().err  # no IMU extrinsic is missing when no IMU is used


def test_missing_extrinsics_warn_and_assume_identity(base_log, tmp_path, capsys):
    log = copy_log(base_log, tmp_path / "notf.bag", lambda tp, t, m, w: [] if tp == "/tf_static" else [(tp, t, m)])
    rc, metrics = _odom(log, tmp_path)
    assert rc == 0
    err = capsys.readouterr().err
    assert "lio: warning: no extrinsic T_base_imu (base -> imu) in /tf_static or --calib: identity assumed" in err
    assert metrics["extrinsics"]["T_base_lidar"] == "identity (assumed)"


def test_calib_file_supplies_missing_extrinsics(base_log, tmp_path, capsys):
    log = copy_log(base_log, tmp_path / "notf.bag", lambda tp, t, m, w: [] if tp == "/tf_static" else [(tp, t, m)])
    truth = json.loads(base_log.with_name("h.truth.json").read_text())
    calib = tmp_path / "calib.yaml"
    accel_bias = truth["imu"]["accel_bias_mps2"]
    calib.write_text(json.dumps({"T_base_imu": truth["T_base_imu"], "T_base_lidar": truth["T_base_lidar"],
                                 "accel_bias_mps2": accel_bias}))
    rc, metrics = _odom(log, tmp_path, "--calib", str(calib))
    assert rc == 0
    assert metrics["extrinsics"]["T_base_imu"] == "--calib"
    # started from the calibrated accelerometer bias, the filter stays near it over 4 s
    np.testing.assert_allclose(metrics["final_accel_bias_mps2"], accel_bias, atol=0.05)
    assert "warning" not in capsys.readouterr().err


def test_imu_gap_longer_than_a_scan_is_bridged_and_counted(base_log, tmp_path):
    gap = (1_700_000_002_000_000_000, 1_700_000_002_300_000_000)

    def drop(tp, t, m, w):
        stamp = m.header.stamp.sec * 10**9 + m.header.stamp.nanosec if tp == "/imu" else 0
        return [] if tp == "/imu" and gap[0] <= stamp < gap[1] else [(tp, t, m)]

    rc, metrics = _odom(copy_log(base_log, tmp_path / "gap.bag", drop), tmp_path)
    assert rc == 0
    assert metrics["scans"]["imu_gaps"] >= 3
    assert metrics["scans"]["used"] == metrics["scans"]["total"]


def test_duplicated_and_backwards_stamps_are_dropped_and_counted(base_log, tmp_path):
    state = {"scans": 0, "imu": 0}

    def dup(tp, t, m, w):
        if tp == SCAN_TOPIC:
            state["scans"] += 1
            if state["scans"] == 12:
                return [(tp, t, m), (tp, t, m)]  # the same scan twice
        if tp == "/imu":
            state["imu"] += 1
            if state["imu"] == 500:  # an IMU sample stamped 1 s in the past
                m.header.stamp.sec -= 1
        return [(tp, t, m)]

    rc, metrics = _odom(copy_log(base_log, tmp_path / "dup.bag", dup), tmp_path)
    assert rc == 0
    assert metrics["stream"]["duplicate_stamps_dropped"] == {SCAN_TOPIC: 1}
    assert metrics["stream"]["backwards_stamps_dropped"] == {"/imu": 1}
    assert metrics["scans"]["total"] == 40


def test_sparse_empty_and_nan_scans_are_skipped_and_counted(base_log, tmp_path):
    state = {"n": 0}

    def damage(tp, t, m, w):
        if tp != SCAN_TOPIC:
            return [(tp, t, m)]
        state["n"] += 1
        n = len(m.data) // m.point_step
        if state["n"] == 10:
            return [(tp, t, _cloud(m, w, keep=20))]  # too few points
        if state["n"] == 20:
            return [(tp, t, _cloud(m, w, nan_rows=np.arange(n)))]  # nothing valid
        if state["n"] == 30:
            return [(tp, t, _cloud(m, w, nan_rows=np.arange(0, n, 3)))]  # a third NaN
        return [(tp, t, m)]

    rc, metrics = _odom(copy_log(base_log, tmp_path / "bad.bag", damage), tmp_path)
    assert rc == 0
    assert metrics["scans"]["skipped_few_points"] == 1
    assert metrics["stream"]["empty_clouds_skipped"] == 1
    assert metrics["stream"]["invalid_points_dropped"] >= 180 * 16 // 3 + 180 * 16 - 200
    assert metrics["scans"]["used"] == 38


def test_a_bad_scan_is_not_a_bad_state(base_log, tmp_path):
    """A scan of another world fails against the IMU prediction and LiDAR-only alike: the scan is bad, the
    prediction stands for it, it stays out of the map, and the IMU state is kept."""
    rng = np.random.default_rng(0)
    state = {"n": 0}

    def garbage(tp, t, m, w):
        if tp == SCAN_TOPIC:
            state["n"] += 1
            if state["n"] == 25:  # a scan of a different world: 2000 points high above the building
                xyz = np.column_stack([rng.uniform(-30, 30, 2000), rng.uniform(-30, 30, 2000), rng.uniform(20, 30, 2000)])
                return [(tp, t, _cloud(m, w, replace_xyz=xyz))]
        return [(tp, t, m)]

    rc, metrics = _odom(copy_log(base_log, tmp_path / "garbage.bag", garbage), tmp_path)
    assert rc == 0
    sc = metrics["scans"]
    assert (sc["registration_failures"], sc["recoveries"]) == (1, 0)
    assert sc["used"] == sc["total"] == 40
    assert metrics["events"] == []


def test_a_bad_imu_state_restarts_from_the_lidar(base_log, tmp_path):
    """0.3 s of accelerometer garbage throws the IMU state off: registration disagrees with the prediction
    while LiDAR-only registration still works, so the run drops the state, registers LiDAR-only scans,
    starts the state again from them and stays accurate."""
    t_bad = {}

    def kick(tp, t, m, w):
        if tp == "/imu":
            stamp = m.header.stamp.sec * 10**9 + m.header.stamp.nanosec
            t_bad.setdefault("t0", stamp + int(1.8e9))
            if t_bad["t0"] <= stamp < t_bad["t0"] + int(0.3e9):
                a = m.linear_acceleration
                return [(tp, t, w.make.imu(stamp, m.header.frame_id, [m.angular_velocity.x, m.angular_velocity.y,
                                                                       m.angular_velocity.z], [a.x + 40.0, a.y, a.z]))]
        return [(tp, t, m)]

    log = copy_log(base_log, tmp_path / "kick.bag", kick)
    rc, metrics = _odom(log, tmp_path, "--gt", "/ground_truth")
    assert rc == 0
    sc = metrics["scans"]
    assert sc["recoveries"] >= 1 and sc["used"] == sc["total"] == 40
    kinds = [e["kind"] for e in metrics["events"]]
    assert kinds[0] == "recovery" and "recovered" in kinds, metrics["events"]
    rc, lidar_only = _odom(log, tmp_path, "--gt", "/ground_truth", "--prior", "constant-velocity", "--force")
    assert rc == 0
    # the IMU run never ends far worse than the same run without the IMU (without the kick it is ~2 cm)
    assert metrics["accuracy"]["ate_trans_rmse_m"] < 1.2 * lidar_only["accuracy"]["ate_trans_rmse_m"]
    assert metrics["accuracy"]["ate_trans_rmse_m"] < 0.15, metrics["accuracy"]


def test_unknown_topic_and_bad_option_values(base_log, tmp_path, capsys):
    rc = main(["odom", str(base_log), "-o", str(tmp_path / "x.tum"), "--lidar-topic", "/nope"])
    assert rc == 2
    assert capsys.readouterr().err.strip() == f"lio: error: {base_log}: topic /nope not found; LiDAR topics here: /points"
    rc = main(["odom", str(base_log), "-o", str(tmp_path / "x.tum"), "--fusion", "kalman"])
    assert rc == 2
    # a choice is checked while parsing, before the log is opened: one line, exit 2
    assert capsys.readouterr().err == ("lio: error: Invalid value for '--fusion': 'kalman' is not one of 'ekf', "
                                       "'complementary'; see 'lio odom --help'\n")
    assert not (tmp_path / "x.tum").exists()


def test_existing_output_is_kept_without_force(base_log, tmp_path, capsys):
    out = tmp_path / "o.tum"
    out.write_text("precious\n")
    assert main(["odom", str(base_log), "-o", str(out), "-q"]) == 2
    assert capsys.readouterr().err.strip() == f"lio: error: {out}: already exists; pass --force to overwrite it"
    assert out.read_text() == "precious\n"


@pytest.mark.parametrize("gt", ["/nope", "{tmp}/missing.gt.tum", "{tmp}/bad.gt.tum"])
def test_bad_ground_truth_is_refused_before_the_odometry_runs(base_log, tmp_path, capsys, monkeypatch, gt):
    """A missing topic or file, or an unreadable file, after a long run lost the whole run's trajectory."""
    from lio_cli.jobs.odom import job as odom_job

    (tmp_path / "bad.gt.tum").write_text("1.0 2.0 3.0\n")
    monkeypatch.setattr(odom_job._OdomRun, "run", lambda self: pytest.fail("odometry ran before the gt was read"))
    gt = gt.format(tmp=tmp_path)
    rc = main(["odom", str(base_log), "-o", str(tmp_path / "x.tum"), "-q", "--gt", gt])
    assert rc == 2
    err = capsys.readouterr().err.strip()
    assert err == {
        "/nope": f"lio: error: {base_log}: topic /nope not found; ground-truth topics here: /ground_truth",
        # an absolute path into a folder that exists is a missing file, not a missing topic
        f"{tmp_path}/missing.gt.tum": f"lio: error: {tmp_path}/missing.gt.tum: no such file, nor a topic of {base_log}",
        f"{tmp_path}/bad.gt.tum": f"lio: error: {tmp_path}/bad.gt.tum: first line has 3 values; expected 8 (TUM: "
                                  "stamp tx ty tz qx qy qz qw) or 12 (KITTI 3x4 pose)",
    }[gt]
    assert not (tmp_path / "x.tum").exists()
