"""``lio deskew`` from the command line: outputs, summary, exit codes and one-line errors."""

import json
import os
from pathlib import Path

import matplotlib.image as mpimg
import pytest

from lio_cli.cli.app import main
from lio_cli.io.logs.reader import open_log
from lio_cli.io.files.trajectory import format_tum, read_tum
from lio_cli.simulation.run import simulate


@pytest.fixture(scope="module")
def logs(tmp_path_factory):
    root = tmp_path_factory.mktemp("logs")
    bag = simulate("handheld", root / "walk.bag", "ros1", duration_s=2.0, seed=4, columns=128, start="moving")
    ros2 = simulate("handheld", root / "walk_ros2", "ros2", duration_s=1.0, seed=4, columns=64, start="moving")
    mcap = simulate("handheld", root / "walk_mcap.mcap", "mcap", duration_s=1.0, seed=4, columns=64, start="moving")
    return bag, ros2, mcap


def records(path):
    with open_log(path) as r:
        return [(x.connection.topic, x.log_time_ns, bytes(x.data)) for x in r.records()]


def err_line(capsys) -> str:
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1, err
    return err


def test_a_run_writes_the_log_its_sidecars_and_the_map_and_says_what_it_did(logs, tmp_path, capsys):
    bag, *_ = logs
    out, ply = tmp_path / "walk_deskewed.mcap", tmp_path / "walk.ply"
    before = (bag.log_path.read_bytes(), bag.gt_path.read_bytes(), bag.log_path.stat().st_mtime_ns)
    rc = main(["deskew", str(bag.log_path), str(out), "--trajectory", str(bag.gt_path), "--map", str(ply)])
    assert rc == 0
    assert (bag.log_path.read_bytes(), bag.gt_path.read_bytes(), bag.log_path.stat().st_mtime_ns) == before
    err = capsys.readouterr().err
    assert "/points: 20/20 scans de-skewed to the scan end" in err
    assert f"motion: trajectory {bag.gt_path} (201 poses of the base over 2.0 s, cubic interpolation)" in err
    assert "other topics: 603 messages converted to mcap" in err  # a ROS 1 bag written as MCAP (ros2 profile)
    sidecars = tmp_path / "walk_deskewed.deskew.metrics.json", tmp_path / "walk_deskewed.deskew.config.yaml"
    preview = tmp_path / "walk.png"
    assert f"map: 0 points in {ply}" not in err and f" points in {ply}\n" in err
    assert f"real time; wrote {out} (mcap), {ply}, {sidecars[0]}, {sidecars[1]}, {preview}\n" in err
    assert err.rstrip().endswith("its clouds are de-skewed: run odometry on it without de-skewing again (kiss-icp: "
                                 f"deskew false)\nnext: lio odom {out} --deskew none")
    for p in (out, ply, *sidecars, preview):
        assert p.exists()
    assert mpimg.imread(preview).shape == (800, 800, 4)  # the map from above
    metrics = json.loads((tmp_path / "walk_deskewed.deskew.metrics.json").read_text())
    assert metrics["scans"]["deskewed"] == 20 and metrics["output_format"] == "mcap"
    assert metrics["motion"]["source"] == "trajectory" and metrics["time_s"]["total"] > 0
    # the written configuration repeats the run
    again = tmp_path / "again.mcap"
    assert main(["deskew", str(bag.log_path), str(again), "--config", str(tmp_path / "walk_deskewed.deskew.config.yaml"),
                 "-q"]) == 0
    assert records(again) == records(out)
    assert capsys.readouterr().err == ""


def test_json_summary_on_stdout(logs, tmp_path, capsys):
    bag, *_ = logs
    rc = main(["deskew", str(bag.log_path), str(tmp_path / "o.bag"), "--trajectory", str(bag.gt_path), "--json", "-q",
               "--topic-suffix", "_deskewed", "--reference", "start"])
    assert rc == 0
    m = json.loads(capsys.readouterr().out)
    assert m["output_topic"] == "/points_deskewed" and m["reference"].startswith("scan start")


def test_an_existing_output_is_kept_without_force(logs, tmp_path, capsys):
    bag, *_ = logs
    out = tmp_path / "o.bag"
    out.write_bytes(b"precious")
    args = ["deskew", str(bag.log_path), str(out), "--trajectory", str(bag.gt_path), "-q"]
    assert main(args) == 2
    assert err_line(capsys) == f"lio: error: {out}: already exists; pass --force to overwrite it"
    assert out.read_bytes() == b"precious" and sorted(p.name for p in tmp_path.iterdir()) == ["o.bag"]
    assert main(args + ["--force"]) == 0
    assert records(out)


def test_the_output_is_never_the_input_or_inside_it(logs, tmp_path, capsys):
    bag, ros2, _ = logs
    log = bag.log_path
    for extra in ([], ["--force"]):
        assert main(["deskew", str(log), str(log), "--trajectory", str(bag.gt_path), *extra]) == 2
        assert err_line(capsys) == (f"lio: error: {log}: is an input of this run (the input {log}); lio never writes "
                                    "over its inputs, whatever the options: choose another output")
    inside = ros2.log_path / "deskewed"
    assert main(["deskew", str(ros2.log_path), str(inside), "--trajectory", str(ros2.gt_path)]) == 2
    assert err_line(capsys) == (f"lio: error: {inside}: is an input of this run (inside the input folder "
                                f"{ros2.log_path}); lio never writes over its inputs, whatever the options: choose "
                                "another output")
    assert not inside.exists()
    tum = tmp_path / "t.tum"
    tum.write_text(format_tum(*read_tum(bag.gt_path)))
    assert main(["deskew", str(log), str(tum), "--trajectory", str(tum), "--force"]) == 2
    assert "is an input of this run" in err_line(capsys)


def test_a_trajectory_that_misses_scans_is_refused_with_strict(logs, tmp_path, capsys):
    bag, *_ = logs
    stamps, poses = read_tum(bag.gt_path)
    half = tmp_path / "half.tum"
    half.write_text(format_tum(stamps[:100], poses[:100]))
    out = tmp_path / "o.bag"
    assert main(["deskew", str(bag.log_path), str(out), "--trajectory", str(half), "--strict"]) == 2
    # the first scan missed: from 1.0 s to its last column, 127/128 of 0.1 s later (1 ns off in the float32 time);
    # the one before, to 0.999 s, is 9 ms past the last pose, within one pose interval (10 ms): extended to it
    assert err_line(capsys) == (f"lio: error: {bag.log_path}: /points: the scan of 1700000001.000000000 s to "
                                "1700000001.099218749 s is after the trajectory ends (1700000000.000000000 s to "
                                "1700000000.990000000 s); without --strict such scans are copied unchanged and counted")
    assert sorted(p.name for p in tmp_path.iterdir()) == ["half.tum"]  # nothing half-written
    assert main(["deskew", str(bag.log_path), str(out), "--trajectory", str(half)]) == 0
    assert "copied unchanged (10 not covered by the motion: after the trajectory ends)" in capsys.readouterr().err


def test_lio_odoms_trajectory_covers_every_scan(logs, tmp_path, capsys):
    """lio odom stamps each pose at its scan's end, so the first scan begins one interval before its trajectory:
    `lio odom ... && lio deskew ... --trajectory odom.tum --strict` was always refused for that scan."""
    bag, *_ = logs
    odom = tmp_path / "o.tum"
    assert main(["odom", str(bag.log_path), "-o", str(odom), "-q"]) == 0
    out = tmp_path / "d.bag"
    assert main(["deskew", str(bag.log_path), str(out), "--trajectory", str(odom), "--strict", "-q"]) == 0
    assert json.loads((tmp_path / "d.deskew.metrics.json").read_text())["scans"]["deskewed"] == 20


def test_a_trajectory_on_another_clock_is_refused_not_copied(logs, tmp_path, capsys):
    """A TUM from 0 beside a log in epoch time covers no scan: the run would be a copy of the log."""
    bag, *_ = logs
    stamps, poses = read_tum(bag.gt_path)
    zero = tmp_path / "zero.tum"
    zero.write_text(format_tum(stamps - stamps[0], poses))
    out = tmp_path / "o.bag"
    assert main(["deskew", str(bag.log_path), str(out), "--trajectory", str(zero), "--map", str(tmp_path / "m.ply")]) == 2
    assert err_line(capsys) == (f"lio: error: {zero}: the trajectory (0.000..2.000 s) covers none of the 20 scans of "
                                "/points (1700000000.000..1700000001.999 s): 1.7e+09 s apart, it looks stamped on "
                                "another clock")
    assert sorted(p.name for p in tmp_path.iterdir()) == ["zero.tum"]  # nothing written
    late = tmp_path / "late.tum"  # near but after every scan: the ranges, no clock guess
    late.write_text(format_tum(stamps + 3_000_000_000, poses))
    assert main(["deskew", str(bag.log_path), str(out), "--trajectory", str(late)]) == 2
    assert err_line(capsys).endswith("covers none of the 20 scans of /points (1700000000.000..1700000001.999 s)")
    assert sorted(p.name for p in tmp_path.iterdir()) == ["late.tum", "zero.tum"]


@pytest.mark.parametrize("log,out,line", [
    (0, "nosuffix", "a ROS 1 bag needs the .bag suffix (OUT has no suffix; readers go by it): name it nosuffix.bag"),
    (0, "o.bag2", "a ROS 1 bag needs the .bag suffix (OUT has '.bag2'; readers go by it): name it o.bag"),
    (2, "nosuffix", "an MCAP file needs the .mcap suffix (OUT has no suffix; readers go by it): name it nosuffix.mcap"),
])
def test_a_bag_or_mcap_file_without_its_suffix_is_refused(logs, tmp_path, capsys, log, out, line):
    path = tmp_path / out
    assert main(["deskew", str(logs[log].log_path), str(path), "--trajectory", str(logs[log].gt_path)]) == 2
    assert err_line(capsys) == f"lio: error: {path}: {line} (a ROS 2 bag, --format ros2, is a folder and needs none)"
    assert not list(tmp_path.iterdir())


def test_a_ros2_output_needs_no_suffix(logs, tmp_path):
    bag = logs[0]
    out = tmp_path / "folder"
    assert main(["deskew", str(bag.log_path), str(out), "--trajectory", str(bag.gt_path), "--format", "ros2", "-q"]) == 0
    assert (out / "metadata.yaml").exists() and records(out)


@pytest.mark.parametrize("args,line", [
    (["--map", "m.xyz"], "lio: error: m.xyz: a map is written as .ply or .pcd; name the file with one of those suffixes"),
    (["--topic-suffix", "a b"], "lio: error: options: topic_suffix: 'a b' is not a topic-name suffix (letters, "
                                "digits, _ and / only, e.g. _deskewed)"),
    (["--format", "zip"], "lio: error: Invalid value for '--format': 'zip' is not one of 'ros1', 'ros2', 'ros2-mcap', "
                          "'mcap'; see 'lio deskew --help'"),
    (["--reference", "middle"], "lio: error: Invalid value for '--reference': 'middle' is not one of 'end', 'start'; "
                                "see 'lio deskew --help'"),
    (["--point-time", "tick"], "lio: error: unknown per-point time convention 'tick' (use velodyne, ouster, livox, "
                               "hesai, azimuth, none, FIELD:UNIT[:abs|rel] or SEC_FIELD+NSEC_FIELD[:abs|rel], e.g. time:s, "
                               "t:ns or time_sec+time_nsec)"),
    (["--motion", "imu"], "lio: error: --trajectory gives the motion; it cannot be combined with --motion imu"),
])
def test_bad_options_are_one_line_and_exit_2(logs, tmp_path, capsys, args, line):
    bag, *_ = logs
    cwd = os.getcwd()
    os.chdir(tmp_path)
    try:
        rc = main(["deskew", str(bag.log_path), "o.bag", "--trajectory", str(bag.gt_path), *args])
    finally:
        os.chdir(cwd)
    assert rc == 2
    assert err_line(capsys) == line
    assert not list(Path(tmp_path).iterdir())


def test_help_states_the_rules_of_the_de_skewed_cloud(capsys):
    assert main(["deskew", "--help"]) == 0
    text = " ".join(capsys.readouterr().out.split())
    for phrase in ("same frame_id, same fields, point order and count", "invalid points stay invalid",
                   "sensor frame at one reference instant", "--reference end", "header stamp is set to that instant",
                   "rewritten relative to it", "A LaserScan topic is written as a PointCloud2", "--topic-suffix",
                   "--trajectory", "--motion constant-velocity", "--strict", "--map"):
        assert phrase in text, phrase


def test_missing_extrinsics_warn_once_each(logs, tmp_path, capsys):
    """Without /tf_static the odometry and the writing pass assume identity for the same extrinsics: one warning each."""
    from lio_cli.io.logs.writer import LogWriter

    bag, *_ = logs
    log = tmp_path / "notf.bag"
    with open_log(bag.log_path) as r, LogWriter(log, "ros1") as w:
        for topic, info in r.topics.items():
            if topic != "/tf_static":
                w.add_topic(topic, info.msgtype)
        for topic, _, t, msg in r.messages():
            if topic != "/tf_static":
                w.write(topic, t, msg)
    assert main(["deskew", str(log), str(tmp_path / "o.bag"), "-q"]) == 0
    err = capsys.readouterr().err
    for name, frame in (("T_base_lidar", "lidar"), ("T_base_imu", "imu")):
        line = f"lio: warning: no extrinsic {name} (base -> {frame}) in /tf_static or --calib: identity assumed"
        assert err.count(line) == 1, err
