"""``lio odom`` end to end on simulated logs with exact ground truth.

Every accuracy threshold here sits between what IMU-primed, IMU-deskewed odometry reaches and what the same
pipeline reaches without IMU priming (constant-velocity prior and deskew) or without deskew; the tests run
both sides, so a pipeline that lost its IMU loop cannot pass.
"""

import json

import numpy as np
import pytest

from lio_cli.cli.app import main
from lio_cli.config import load_model
from lio_cli.config.odom import OdomConfig
from lio_cli.evaluation import EvalOptions, evaluate
from lio_cli.model.trajectory import Trajectory
from lio_cli.io.logs.reader import open_log
from lio_cli.io.sensors.stream import SensorStream
from lio_cli.io.files.trajectory import read_tum
from lio_cli.simulation.run import simulate

DURATION_S = 6.0
# scenario -> (format, ATE threshold in m, alternatives that must exceed it)
CASES = {
    "handheld": ("ros1", 0.015, ("lidar-only", "no-deskew")),
    "drive": ("mcap", 0.15, ("lidar-only", "no-deskew")),
    "corridor": ("ros2", 0.20, ("lidar-only",)),
    "planar": ("mcap", 0.012, ("lidar-only", "no-deskew")),
}
MODES = {
    "lio": [],
    "lidar-only": ["--prior", "constant-velocity", "--deskew", "constant-velocity"],
    "no-deskew": ["--deskew", "none"],
}
SUFFIX = {"ros1": ".bag", "mcap": ".mcap", "ros2": ""}


@pytest.fixture(scope="module")
def logs(tmp_path_factory):
    root = tmp_path_factory.mktemp("sim")
    out = {}
    for scenario, (fmt, _, _) in CASES.items():
        res = simulate(scenario, root / f"{scenario}{SUFFIX[fmt]}", fmt, duration_s=DURATION_S, seed=1, columns=360)
        out[scenario] = res
    return out


def _ate(gt_path, est_path, max_diff_ns=2_000_000) -> float:
    ref = Trajectory(*read_tum(gt_path), name="gt")
    est = Trajectory(*read_tum(est_path), name="est")
    return evaluate(ref, est, EvalOptions(max_diff_ns=max_diff_ns)).stats["ape"]["trans"]["rmse"]


def _run(log, out, extra=(), capsys=None):
    rc = main(["odom", str(log), "-o", str(out), "-q", *extra])
    return rc


@pytest.mark.parametrize("scenario", list(CASES))
def test_imu_primed_odometry_beats_threshold_that_lidar_only_misses(scenario, logs, tmp_path):
    fmt, threshold, worse = CASES[scenario]
    res = logs[scenario]
    ate = {}
    for mode in ("lio", *worse):
        out = tmp_path / f"{mode}.tum"
        assert _run(res.log_path, out, MODES[mode]) == 0
        ate[mode] = _ate(res.gt_path, out)
    assert ate["lio"] < threshold, ate
    for mode in worse:
        assert ate[mode] > threshold, ate


def test_outputs_metrics_and_config_beside_trajectory(logs, tmp_path):
    res = logs["corridor"]
    out = tmp_path / "c.tum"
    assert _run(res.log_path, out) == 0
    metrics = json.loads((tmp_path / "c.odom.metrics.json").read_text())
    written = load_model(OdomConfig, tmp_path / "c.odom.config.yaml")
    assert (written.deskew, written.planar) == ("imu", False)  # resolved: no "auto" left
    assert (written.input.lidar_topic, written.input.imu_topic, written.input.wheel_topic) == ("/points", "/imu", "/wheel/odom")
    assert (written.input.base_frame, metrics["format"]) == ("base", "ros2")
    assert written.input.format is None  # detected, not asked for: it must not bind the next log
    sc = metrics["scans"]
    assert sc["total"] == sc["used"] == 60
    assert sc["degenerate"] > 40  # a featureless corridor: the axis is unconstrained in most scans
    assert sc["wheel_updates"] == 60  # every scan: the wheel speed over its interval (the first: its sweep)
    assert sc["lidar_only_scans"] == 0  # the start-up window was replayed IMU-primed
    assert metrics["initialisation_static"] is True
    assert metrics["start"]["kind"] == "standing" and metrics["start"]["scans"] == 11
    assert metrics["extrinsics"]["T_base_imu"].startswith("/tf_static")
    assert metrics["real_time_factor"] > 0
    assert set(metrics["time_s"]) >= {"read_decode", "propagate", "deskew", "register", "fuse", "total"}


def test_pose_stamps_are_the_instants_scans_were_deskewed_to(logs, tmp_path):
    res = logs["handheld"]
    out = tmp_path / "h.tum"
    assert _run(res.log_path, out) == 0
    stamps, _ = read_tum(out)
    with open_log(res.log_path) as reader:
        ends = [int(r.data.point_stamps_ns.max()) for r in SensorStream(reader, {"lidar": "/points"})]
    np.testing.assert_array_equal(stamps, ends)  # exact ns: the scan's last point


def test_stdout_output_and_frame_option(logs, tmp_path, capsys):
    res = logs["planar"]
    assert main(["odom", str(res.log_path), "-o", "-", "-q", "--frame", "lidar"]) == 0
    lines = capsys.readouterr().out.splitlines()
    assert len(lines) == 60  # 10 Hz x 6 s, written only to stdout
    assert not list(tmp_path.iterdir())
    truth = json.loads(res.truth_path.read_text())
    vals = np.array([float(v) for v in lines[0].split()[1:4]])
    # first pose of the lidar frame: base at the origin composed with the lidar offset
    np.testing.assert_allclose(vals, np.asarray(truth["T_base_lidar"])[:3, 3], atol=0.02)


def test_gt_option_scores_against_log_topic_or_file(logs, tmp_path, capsys):
    res = logs["corridor"]
    out = tmp_path / "c.tum"
    assert main(["odom", str(res.log_path), "-o", str(out), "-q", "--gt", "/ground_truth"]) == 0
    acc = json.loads((tmp_path / "c.odom.metrics.json").read_text())["accuracy"]
    # the same number lio evaluate gives on the ground-truth file (which rounds poses to 1e-9 m)
    assert acc["ate_trans_rmse_m"] == pytest.approx(_ate(res.gt_path, out, 20_000_000), rel=1e-6)
    assert acc["matches"] == 60
    err = capsys.readouterr().err
    assert err.startswith(f"against /ground_truth: ATE {acc['ate_trans_rmse_m']:.4f} m")
    assert main(["odom", str(res.log_path), "-o", str(out), "-q", "--force", "--gt", str(res.gt_path)]) == 0
    acc_file = json.loads((tmp_path / "c.odom.metrics.json").read_text())["accuracy"]
    assert acc_file["ate_trans_rmse_m"] == pytest.approx(_ate(res.gt_path, out, 20_000_000), rel=1e-6)


def test_gt_of_a_platform_standing_still_is_scored_from_the_first_pose(tmp_path, capsys):
    """A reference whose positions are one point has no rotation to align by: the run once stopped with exit 2
    and wrote nothing, naming an --align odom does not have. Scored from the first pose, as lio evaluate
    --align origin scores it."""
    res = simulate("handheld", tmp_path / "still.bag", "ros1", duration_s=1.4, seed=1, columns=180)  # rests 1.5 s
    out = tmp_path / "s.tum"
    assert main(["odom", str(res.log_path), "-o", str(out), "-q", "--gt", str(res.gt_path)]) == 0
    acc = json.loads((tmp_path / "s.odom.metrics.json").read_text())["accuracy"]
    assert acc["alignment"] == "origin" and acc["matches"] == 14
    ref, est = Trajectory(*read_tum(res.gt_path), name="gt"), Trajectory(*read_tum(out), name="est")
    expected = evaluate(ref, est, EvalOptions(max_diff_ns=2_000_000, align="origin")).stats["ape"]["trans"]["rmse"]
    assert acc["ate_trans_rmse_m"] == pytest.approx(expected, rel=1e-6) and expected < 0.02
    assert capsys.readouterr().err.startswith(
        f"against {res.gt_path}: ATE {expected:.4f} m, {acc['ate_rot_rmse_deg']:.3f} deg (rmse over 14 poses aligned at "
        "the first: the reference's positions lie on a line or a point); RPE over 1 s: ")


def test_a_reference_near_a_line_says_its_rotation_error_means_little(tmp_path, capsys):
    """2 s of a car cruising straight: SE(3) alignment may spin the estimate about the line (87 deg of "rotation
    error" on such a log, the translation right); the score says so, and a walk's does not."""
    res = simulate("drive", tmp_path / "line.bag", "ros1", duration_s=2.0, seed=0, columns=360, start="moving")
    out = tmp_path / "l.tum"
    assert main(["odom", str(res.log_path), "-o", str(out), "--gt", str(res.gt_path)]) == 0
    acc = json.loads((tmp_path / "l.odom.metrics.json").read_text())["accuracy"]
    assert acc["alignment"] == "se3" and acc["ate_trans_rmse_m"] < 0.1
    assert acc["note"].startswith("the reference's positions lie near a line (they stray ")
    assert acc["note"] in capsys.readouterr().err
    walk = simulate("handheld", tmp_path / "walk.bag", "ros1", duration_s=10.0, seed=0, columns=360)  # it turns
    assert main(["odom", str(walk.log_path), "-o", str(tmp_path / "w.tum"), "-q", "--gt", str(walk.gt_path)]) == 0
    assert json.loads((tmp_path / "w.odom.metrics.json").read_text())["accuracy"]["note"] is None


@pytest.mark.parametrize("scenario, threshold", [("handheld", 0.08), ("corridor", 0.20)])
def test_complementary_filter_also_beats_lidar_only(scenario, threshold, logs, tmp_path):
    res = logs[scenario]
    ate = {}
    for mode, extra in (("complementary", ["--fusion", "complementary"]), ("lidar-only", MODES["lidar-only"])):
        out = tmp_path / f"{mode}.tum"
        assert _run(res.log_path, out, extra) == 0
        ate[mode] = _ate(res.gt_path, out)
    assert ate["complementary"] < threshold < ate["lidar-only"], ate


def test_written_config_repeats_the_run_byte_for_byte(logs, tmp_path):
    """The .config.yaml holds the whole job (topics, calibration, base frame, options): --config alone repeats it."""
    res = logs["handheld"]
    cal = tmp_path / "cal.yaml"
    cal.write_text("imu_time_offset_s: 0.001\ngyro_bias_radps: [0.001, -0.002, 0.0005]\n")
    first = tmp_path / "first.tum"
    flags = ["--fusion", "complementary", "--alpha", "0.9", "--lidar-topic", "/points", "--calib", str(cal),
             "--base-frame", "base", "--point-time", "velodyne", "--no-wheel"]
    assert _run(res.log_path, first, flags) == 0
    written = load_model(OdomConfig, tmp_path / "first.odom.config.yaml")
    assert written.calibration.imu_time_offset_s == 0.001 and written.input.point_time == "velodyne"
    assert written.fusion.method == "complementary" and written.use_wheel is False
    again = tmp_path / "again.tum"
    assert _run(res.log_path, again, ["--config", str(tmp_path / "first.odom.config.yaml")]) == 0
    assert again.read_bytes() == first.read_bytes()
    default = tmp_path / "default.tum"
    assert _run(res.log_path, default) == 0
    assert default.read_bytes() != first.read_bytes()  # the flags mattered, so the config carried them
    # a flag given with --config overrides that one field only
    over = tmp_path / "over.tum"
    assert _run(res.log_path, over, ["--config", str(tmp_path / "first.odom.config.yaml"), "--alpha", "0.5"]) == 0
    cfg = load_model(OdomConfig, tmp_path / "over.odom.config.yaml")
    assert (cfg.fusion.alpha, cfg.fusion.method, cfg.calibration.imu_time_offset_s) == (0.5, "complementary", 0.001)
