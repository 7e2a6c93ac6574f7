"""``lio fuse`` end to end through ``main([...])``: the files it writes, ``--config`` repeating a run byte for
byte, ``-o -``, ``--cov``, ``--plot``, bad input (one line, exit 2, nothing written), ``lio evaluate`` taking the
fused output against a NavSatFix topic, and the real recordings of ``../shared/real_logs``."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
import yaml

from lio_cli.cli.app import main
from lio_cli.io.files.trajectory import read_tum
from lio_cli.io.logs.writer import LogWriter
from lio_cli.simulation.run import simulate

RL_END = np.array([1.0206, 3.4292, 0.7419])  # robot_localization's test_ekf_localization_node_bag2 end point
RL_TOL_M = 0.1383
GPS_SIGMA_M = 1.0  # the simulator's horizontal GPS noise




@pytest.fixture(scope="module")
def planar(tmp_path_factory) -> Path:
    log = tmp_path_factory.mktemp("fuse_cli") / "office.bag"
    simulate("planar", log, duration_s=12.0, seed=2, gps=True)
    return log


def _run(capsys, *args) -> tuple[int, str, str]:
    code = main(["fuse", *map(str, args)])
    out, err = capsys.readouterr()
    return code, out, err


def test_files_and_config_round_trip(capsys, planar, tmp_path):
    out = tmp_path / "fused.tum"  # smoothed by default: the factor graph (the log has an accelerometer)
    code, _, err = _run(capsys, planar, "-o", out, "--rate", 50, "--cov", tmp_path / "fused.cov",
                        "--plot", tmp_path / "plots")
    assert code == 0, err
    stamps, poses = read_tum(out)
    assert np.all(np.diff(stamps) == 20_000_000) and np.allclose(poses[0, :3, 3], 0.0)
    m = json.loads((tmp_path / "fused.fuse.metrics.json").read_text())
    assert m["sources_used"] == ["gps", "imu", "wheel"] and m["smoothed"] is True
    assert m["smoother"] == {"kind": "factor_graph", "why": "over the whole log, with the accelerometer"}
    assert "\nsmooth: true\n" in (tmp_path / "fused.fuse.config.yaml").read_text()
    assert m["sources"]["gps"]["rejected"]["no_fix"]["why"] == "the GPS fix status said invalid"
    assert set(m["time_s"]) == {"read", "fuse", "total", "cpu"} and m["output"]["poses"] == len(stamps)
    cov_lines = (tmp_path / "fused.cov").read_text().splitlines()
    assert cov_lines[0].startswith("# lio fuse per-pose covariance") and len(cov_lines) == len(stamps) + 1
    row = np.array(cov_lines[1].split(), float)
    assert len(row) == 37 and row[0] == stamps[0] * 1e-9
    for name in ("fuse_top_view.png", "fuse_speed_yaw_rate.png"):
        assert (tmp_path / "plots" / name).read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    assert "smoother:" not in err  # said only when it is not the factor graph
    assert "poses (50 Hz), planar + factor graph: imu" in err and "estimator: planar (a wheeled robot near a plane" in err
    again = tmp_path / "again.tum"
    code, _, err = _run(capsys, planar, "--config", tmp_path / "fused.fuse.config.yaml", "-o", again)
    assert code == 0, err
    assert again.read_bytes() == out.read_bytes()


def test_stdout_writes_nothing_else(capsys, planar, tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    code, out, err = _run(capsys, planar, "-o", "-", "--rate", 20, "-q")
    assert code == 0, err
    lines = out.splitlines()
    assert len(lines) == 241 and len(lines[0].split()) == 8
    assert list(tmp_path.iterdir()) == []


@pytest.mark.parametrize("rate", ["0", "-5"])
def test_rate_not_positive(capsys, planar, tmp_path, monkeypatch, rate):
    monkeypatch.chdir(tmp_path)
    code, out, err = _run(capsys, planar, "--rate", rate)
    assert code == 2 and out == ""
    assert err.strip() == f"lio: error: --rate must be a positive number of Hz, got {float(rate):g}"
    assert list(tmp_path.iterdir()) == []


def test_no_motion_source_is_one_line_and_writes_nothing(capsys, tmp_path, monkeypatch):
    log = tmp_path / "gps_only.bag"
    with LogWriter(log, "ros1") as w:
        w.add_topic("/fix", "sensor_msgs/msg/NavSatFix")
        for k in range(5):
            t = 1_700_000_000 * 10**9 + k * 10**8
            w.write("/fix", t, w.make.navsatfix(t, "gps", 47.0, 8.0, 400.0))
    monkeypatch.chdir(tmp_path)
    code, _, err = _run(capsys, log, "--plot", "plots", "--cov", "c.cov")
    assert code == 2
    assert err.strip() == (f"lio: error: {log}: no motion source: no IMU or wheel odometry topic found and no "
                           "odometry given (GPS alone cannot be fused); give --odom FILE, --odom-topic, --imu-topic "
                           "or --wheel-topic")
    assert sorted(p.name for p in tmp_path.iterdir()) == ["gps_only.bag"]


def test_evaluate_takes_the_fused_output_against_the_gps_topic(capsys, planar, tmp_path):
    out = tmp_path / "f.tum"
    assert _run(capsys, planar, "-o", out, "-q")[0] == 0
    code = main(["evaluate", f"{planar}:/gps/fix", str(out), "--align", "posyaw", "--json"])
    text, err = capsys.readouterr()
    assert code == 0, err
    r = json.loads(text)["estimates"][0]
    assert r["translation_only"] is True and r["poses"]["matched"] > 40
    assert r["ape"]["trans"]["rmse"] < 2.5 * GPS_SIGMA_M  # the GPS noise, not a broken trajectory


def test_no_smooth_is_the_filter_alone(capsys, planar, tmp_path):
    out = tmp_path / "filtered.tum"
    code, _, err = _run(capsys, planar, "-o", out, "--rate", 50, "--no-smooth")
    assert code == 0, err
    m = json.loads((tmp_path / "filtered.fuse.metrics.json").read_text())
    assert m["smoothed"] is False and m["smoother"] == {"kind": None, "why": "--no-smooth: the filter alone"}
    assert m["core"]["smoothed"] is False and m["estimator"] == "planar"
    assert "\nsmooth: false\n" in (tmp_path / "filtered.fuse.config.yaml").read_text()
    assert "smoother: none (--no-smooth: the filter alone)" in err and "poses (50 Hz), planar: imu" in err
    smoothed = tmp_path / "smoothed.tum"
    assert _run(capsys, planar, "-o", smoothed, "--rate", 50, "-q")[0] == 0
    assert not np.allclose(read_tum(smoothed)[1], read_tum(out)[1], atol=1e-3)  # a different trajectory


def test_json_summary(capsys, planar, tmp_path):
    code, out, err = _run(capsys, planar, "-o", tmp_path / "j.tum", "--json", "--use", "imu:gyro", "--use",
                          "wheel:speed,yaw_rate", "--estimator", "planar")
    assert code == 0, err
    m = json.loads(out)
    assert m["estimator"] == "planar" and m["sources_used"] == ["imu", "wheel"]
    assert m["sources"]["wheel"]["measurements"] == ["speed", "yaw_rate"]
    assert "gps" not in m["sources"]


def test_jackal_ends_where_robot_localization_does(real_logs, capsys, tmp_path):
    out = tmp_path / "jackal.tum"
    code, _, err = _run(capsys, real_logs / "jackal_imu_wheel" / "jackal.bag", "-o", out)
    assert code == 0, err
    _, poses = read_tum(out)
    assert np.linalg.norm(poses[-1, :3, 3] - RL_END) <= RL_TOL_M


def test_groovy_needs_the_xsens_extrinsic_and_then_runs(real_logs, capsys, tmp_path):
    log = real_logs / "groovy_imu_wheel_stereo" / "groovy.bag"
    code, _, err = _run(capsys, log, "-o", tmp_path / "g.tum")
    assert code == 2 and err.strip() == (
        f"lio: error: {log}: IMU /xsens/imu_data is in frame 'xsens_sensor' and neither /tf_static nor --calib gives "
        "T_base_imu (base -> xsens_sensor); pass --calib with T_base_imu (lio calibrate writes one)")
    calib = tmp_path / "calib.yaml"
    calib.write_text("T_base_imu: [[1, 0, 0, 0], [0, 1, 0, 0], [0, 0, 1, 0], [0, 0, 0, 1]]\n")
    code, _, err = _run(capsys, log, "-o", tmp_path / "g.tum", "--calib", calib, "--rate", 20)
    assert code == 0, err
    m = json.loads((tmp_path / "g.fuse.metrics.json").read_text())
    assert m["sources"]["imu"]["topic"] == "/xsens/imu_data"  # the all-zero IMU beside it is left out
    assert m["extrinsics"]["wheel_twist"].startswith("parent frame")  # this driver's twist is in its odom frame


def test_ardrone_twist_only_runs(real_logs, capsys, tmp_path):
    code, _, err = _run(capsys, real_logs / "ardrone_twist_only" / "ardrone.bag", "-o", tmp_path / "a.tum", "--rate", 50)
    assert code == 0, err
    m = json.loads((tmp_path / "a.fuse.metrics.json").read_text())
    assert m["sources"]["wheel"]["measurements"] == ["velocity"]  # a drone: lateral speed, no wheel constraint
    assert m["updates"]["wheel"] == 25217


@pytest.mark.parametrize("args, message", [
    (["-o", "f.tum", "--cov", "f.tum"], "f.tum: would be both the trajectory (-o) and the covariance file (--cov)"),
    (["-o", "f3.tum", "--cov", "f3.fuse.metrics.json"],
     "f3.fuse.metrics.json: would be both the metrics file written beside -o f3.tum and the covariance file (--cov)"),
    (["-o", "f4.tum", "--cov", "f4.fuse.config.yaml"],
     "f4.fuse.config.yaml: would be both the config file written beside -o f4.tum and the covariance file (--cov)"),
    (["-o", "f2.tum", "--plot", "f2.tum"], "f2.tum: would be both the trajectory (-o) and the plot folder (--plot)"),
    (["-o", "-", "--cov", "p", "--plot", "p"],
     "p: would be both the covariance file (--cov) and the plot folder (--plot)"),
    (["-o", "g.tum", "--plot", "p", "--cov", "p/fuse_top_view.png"],
     "p/fuse_top_view.png: would be both the covariance file (--cov) and the plot fuse_top_view.png of --plot p"),
])
def test_outputs_that_share_a_path_are_refused_before_anything_is_written(capsys, planar, tmp_path, monkeypatch,
                                                                         args, message):
    monkeypatch.chdir(tmp_path)
    code, out, err = _run(capsys, planar, *args, "-q")
    assert code == 2 and out == ""
    assert err.strip() == f"lio: error: {message}; give each output its own path"
    assert list(tmp_path.iterdir()) == []


def test_force_does_not_let_one_output_replace_another(capsys, planar, tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    (tmp_path / "f.tum").write_text("keep\n")
    (tmp_path / "link.cov").symlink_to("f.tum")
    code, _, err = _run(capsys, planar, "-o", "f.tum", "--cov", "link.cov", "--force", "-q")
    assert code == 2
    assert err.strip() == ("lio: error: link.cov: would be both the trajectory (-o) and the covariance file (--cov); "
                           "give each output its own path")
    assert sorted(p.name for p in tmp_path.iterdir()) == ["f.tum", "link.cov"]
    assert (tmp_path / "f.tum").read_text() == "keep\n"


@pytest.mark.parametrize("option, what", [("--cov", "the covariance to a file"),
                                          ("--plot", "PNG files into a folder")])
def test_dash_is_no_stdout_for_cov_or_plot(capsys, planar, tmp_path, monkeypatch, option, what):
    monkeypatch.chdir(tmp_path)
    code, out, err = _run(capsys, planar, "-o", "f.tum", option, "-", "-q")
    assert code == 2 and out == ""
    assert err.strip() == f"lio: error: {option} writes {what}, not standard output: give {option} a path"
    assert list(tmp_path.iterdir()) == []


def test_a_rate_the_memory_budget_cannot_hold_is_refused_and_writes_nothing(capsys, planar, tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)  # --rate 1e6 on a 20 s log reached 24 GB and was OOM-killed; 1e5 took 3 GB
    code, out, err = _run(capsys, planar, "--rate", "1e5", "-o", "f.tum", "--cov", "f.cov", "--plot", "p")
    assert code == 2 and out == ""
    assert err.strip() == (
        "lio: error: fusing needs about 1921 MB, over the memory budget of 1024 MB (--max-memory), and a 12 s log is "
        "too short to fuse in chunks (that needs over 60 s): --rate 100000 Hz is 500 times the IMU rate of 200 Hz, "
        "and poses between IMU samples carry no measurement of their own: lower --rate to 200 Hz or less, or raise "
        "--max-memory to 1922 (MB) or more")
    assert list(tmp_path.iterdir()) == []


@pytest.mark.parametrize("wheel, weighed", [("wheel", True), ("wheel:", True), ("wheel:speed", False)])
def test_bare_use_wheel_weighs_the_yaw_rate_as_the_default_does(capsys, planar, tmp_path, wheel, weighed):
    out = tmp_path / "w.tum"
    code, _, err = _run(capsys, planar, "-o", out, "--use", "imu", "--use", wheel, "--quiet")
    assert code == 0, err
    m = json.loads(out.with_name("w.fuse.metrics.json").read_text())
    check = m["core"]["wheel_yaw_check"]
    assert (check is not None) is weighed
    # unequal radii (1.01 and 0.99): the yaw rate follows the speed, which no scale holds: weighed, left out
    assert not weighed or check["why"].startswith("the wheels' yaw rate follows their speed (")
    assert m["sources"]["wheel"]["measurements"] == ["speed"]
    assert yaml.safe_load(out.with_name("w.fuse.config.yaml").read_text())["weigh_wheel_yaw"] is weighed


def test_a_stop_after_a_moving_start_is_said(capsys, tmp_path):
    """A car already moving at its first sample stops from 8 to 12 s: the summary says where it stood still, the
    IMU's line counts the zero-rate updates, and metrics.json holds the span inside the stop."""
    log = tmp_path / "lights.mcap"
    simulate("drive", log, duration_s=20.0, seed=8, lidar=False, start="moving", stops=((8.0, 4.0),))
    out = tmp_path / "fused.tum"
    code, _, err = _run(capsys, log, "-o", out, "--rate", 50)
    assert code == 0, err
    assert "at rest: 1 stop after the start (3.5 s) where the wheels (or odometry) and the IMU stood still" in err
    assert " zero rate updates" in err
    m = json.loads((tmp_path / "fused.fuse.metrics.json").read_text())
    (a, b), = (np.array(m["core"]["rest"]["span_ns"]) - json.loads(log.with_suffix(".truth.json").read_text())
               ["start_ns"]) * 1e-9
    assert 8.0 <= a < 8.8 and 11.2 < b <= 12.0
