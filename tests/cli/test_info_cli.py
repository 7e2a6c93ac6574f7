"""`lio info` end to end: every format x every per-point time convention, and every bad input.

Bad input is one line on stderr, ``lio: error: <file>: <what> ...``, exit code 2, no traceback.
Truncated logs: a ROS 1 bag or MCAP file cut short has lost its index/summary, so opening it already
fails (exit 2, "truncated or corrupted"); corruption in the middle of an intact file may not touch what
`lio info` reads (index, first scan, /tf_static), so plain `info` can succeed, and `info --check`, which
decodes everything, fails with exit 2.
"""

from __future__ import annotations

import json
import re
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from lio_cli import __version__
from lio_cli.cli.app import main

N = 40  # points per test scan
STEP_NS = 1_953_125  # 1/512 s


def run(capsys, *argv: str) -> tuple[int, str, str]:
    rc = main([str(a) for a in argv])
    out, err = capsys.readouterr()
    return rc, out, err


def assert_one_line_error(rc: int, err: str, expected: str | re.Pattern) -> None:
    assert rc == 2
    assert "Traceback" not in err
    lines = err.strip("\n").split("\n")
    assert len(lines) == 1, err
    if isinstance(expected, re.Pattern):
        assert expected.fullmatch(lines[0]), lines[0]
    else:
        assert lines[0] == expected


def _xyz(arr):
    az = 2 * np.pi * np.arange(len(arr)) / len(arr)
    arr["x"], arr["y"], arr["z"] = 5 * np.cos(az), 5 * np.sin(az), 0.5


def cloud_with(field: str | None, dtype: str | None, values) -> np.ndarray:
    fields = [("x", "<f4"), ("y", "<f4"), ("z", "<f4"), ("intensity", "<f4")]
    if field:
        fields.append((field, dtype))
    arr = np.zeros(N, dtype=fields)
    _xyz(arr)
    if field:
        arr[field] = values
    return arr


K = np.arange(N)
# convention id -> (field, dtype, values at header T (as a function of T in s), name, absolute, marks, span ns)
CONVENTIONS = {
    "velodyne": ("time", "<f4", lambda T: K / 512.0, "velodyne", False, "start", (N - 1) * STEP_NS),
    "ouster": ("t", "<u4", lambda T: K * 2_000_000, "ouster", False, "start", (N - 1) * 2_000_000),
    "livox": ("offset_time", "<u4", lambda T: K * 1_000_000, "livox", False, "start", (N - 1) * 1_000_000),
    "hesai": ("timestamp", "<f8", lambda T: T + K / 512.0, "hesai", True, "start", (N - 1) * STEP_NS),
    "timestamps": ("timestamps", "<f8", lambda T: T + K / 512.0, "stamps", True, "start", (N - 1) * STEP_NS),
    "stamps": ("stamps", "<f8", lambda T: K / 512.0, "stamps", False, "start", (N - 1) * STEP_NS),
    "header-at-end": ("time", "<f4", lambda T: (K - (N - 1)) / 512.0, "velodyne", False, "end", (N - 1) * STEP_NS),
    "azimuth": (None, None, None, "azimuth", False, "start", (N - 1) * 100_000_000 // N),
}


@pytest.mark.parametrize("conv", CONVENTIONS)
def test_info_json_every_format_and_time_convention(logs, capsys, write_format, conv):
    field, dtype, values, name, absolute, marks, span_ns = CONVENTIONS[conv]
    path = logs.sensor_log(
        write_format, duration_s=0.3,
        cloud=lambda t: cloud_with(field, dtype, values(t // 10**9 + (t % 10**9) * 1e-9) if values else None))
    rc, out, err = run(capsys, "info", path, "--json")
    assert rc == 0, err
    s = json.loads(out)
    assert s["format"] == logs.READ_FORMAT[write_format]
    assert s["start_ns"] == logs.T0_NS and s["messages"] == 1 + 3 + 30 + 6 + 3
    topics = {t["topic"]: t for t in s["topics"]}
    assert topics["/imu"] == {"topic": "/imu", "type": "sensor_msgs/msg/Imu", "count": 30, "rate_hz": 100.0}
    assert topics["/points"]["count"] == 3 and topics["/points"]["rate_hz"] == 10.0
    (scan,) = s["scans"]
    assert scan["topic"] == "/points" and scan["frame_id"] == "velodyne"
    assert scan["points"] == scan["valid_points"] == N
    assert [f["name"] for f in scan["fields"]] == ["x", "y", "z", "intensity"] + ([field] if field else [])
    tc = scan["time_convention"]
    assert (tc["name"], tc["field"], tc["absolute"], tc["header_stamp_marks"]) == (name, field, absolute, marks)
    assert tc["scan_duration_s"] == pytest.approx(span_ns * 1e-9, abs=1e-6)
    assert {(f["parent"], f["child"]) for f in s["static_transforms"]} == {("base_link", "imu_link"), ("imu_link", "velodyne")}
    assert s["frames"] == ["base_link", "imu_link", "velodyne"]


def test_info_human_table(logs, capsys):
    path = logs.sensor_log("ros1", duration_s=0.3)
    rc, out, err = run(capsys, "info", path)
    assert rc == 0 and err == ""
    assert f"{path}  (ros1)" in out
    assert re.search(r"^start    1700000000\.000 s   2023-11-14 22:13:20\.000 UTC$", out, re.M), out
    assert re.search(r"^end      1700000000\.\d{3} s   2023-11-14 22:13:20\.\d{3} UTC$", out, re.M), out
    assert re.search(r"/imu\s+sensor_msgs/msg/Imu\s+30\s+100\.00", out)
    assert "velodyne: field 'time' in s, relative to header; header stamp marks the scan's start" in out
    assert "imu_link -> velodyne" in out and "fields      x:float32, y:float32, z:float32, intensity:float32, time:float32" in out


def test_info_check_passes_on_good_log(logs, capsys):
    path = logs.sensor_log("ros2", duration_s=0.3)
    rc, out, err = run(capsys, "info", path, "--check", "--json")
    assert rc == 0
    assert json.loads(out)["check"]["checked"] == {"/points": 3, "/imu": 30, "/odom": 6, "/ground_truth": 3}
    assert "check passed" not in err  # JSON mode keeps stderr quiet


def test_info_point_time_override(logs, capsys):
    path = logs.sensor_log("mcap", duration_s=0.1)
    rc, out, _ = run(capsys, "info", path, "--json", "--point-time", "azimuth")
    assert rc == 0 and json.loads(out)["scans"][0]["time_convention"]["name"] == "azimuth"
    rc, _, err = run(capsys, "info", path, "--point-time", "nonsense")
    assert_one_line_error(rc, err, re.compile(r"lio: error: unknown per-point time convention 'nonsense' .*"))


def test_info_metadata_yaml_and_format_override(logs, capsys, tmp_path):
    path = logs.sensor_log("ros2-mcap", duration_s=0.1)
    rc, out, _ = run(capsys, "info", path / "metadata.yaml", "--json")
    assert rc == 0 and json.loads(out)["format"] == "ros2"
    rc, out, _ = run(capsys, "info", path / f"{path.name}.mcap", "--format", "mcap", "--json")
    assert rc == 0 and json.loads(out)["format"] == "mcap"


# ---- bad input: one line, exit 2 -------------------------------------------------------------------


def test_missing_path(capsys, tmp_path):
    p = tmp_path / "nope.bag"
    rc, _, err = run(capsys, "info", p)
    assert_one_line_error(rc, err, f"lio: error: {p}: no such file or folder")


@pytest.mark.parametrize("content", [np.random.default_rng(0).bytes(4096), b"topic,stamp\n/imu,1\n"], ids=["random", "text"])
def test_not_a_log(capsys, tmp_path, content):
    p = tmp_path / "data.bag"
    p.write_bytes(content)
    rc, _, err = run(capsys, "info", p)
    assert_one_line_error(rc, err, f"lio: error: {p}: not a ROS 1 bag, ROS 2 bag or MCAP file (unrecognised content)")


def test_folder_without_log(capsys, tmp_path):
    rc, _, err = run(capsys, "info", tmp_path)
    assert_one_line_error(rc, err, f"lio: error: {tmp_path}: folder holds no log (expected a ROS 2 bag with "
                                   "metadata.yaml, .bag files or one .mcap)")


@pytest.mark.parametrize("fmt,what", [("ros1", "ros1 log"), ("mcap", "MCAP"), ("ros2-mcap", "ros2 log")])
def test_truncated_log(logs, capsys, fmt, what):
    path = logs.sensor_log(fmt, duration_s=0.5)
    target = path / f"{path.name}.mcap" if fmt == "ros2-mcap" else path
    data = target.read_bytes()
    target.write_bytes(data[: len(data) // 2])
    for extra in ([], ["--check"]):
        rc, _, err = run(capsys, "info", path, *extra)
        assert_one_line_error(rc, err, re.compile(
            rf"lio: error: {re.escape(str(path))}: cannot open as {what} \(.+\); the (log|file) may be truncated or corrupted"))


def test_truncated_ros2_sqlite_bag(logs, capsys):
    path = logs.sensor_log("ros2", duration_s=0.5)
    db = path / f"{path.name}.db3"
    data = db.read_bytes()
    db.write_bytes(data[: len(data) // 2])
    rc, _, err = run(capsys, "info", path, "--check")
    assert_one_line_error(rc, err, re.compile(rf"lio: error: {re.escape(str(path))}: .*truncated or corrupted"))


def test_corrupted_bytes_in_the_middle_fail_check(logs, capsys):
    path = logs.sensor_log("ros1", duration_s=0.5)
    data = bytearray(path.read_bytes())
    pos = data.find(b"op=\x02", len(data) // 2)  # a message record's op code in the middle of the file
    data[pos + 3] = 0x7F
    path.write_bytes(bytes(data))
    rc, _, err = run(capsys, "info", path, "--check")
    assert_one_line_error(rc, err, re.compile(
        rf"lio: error: {re.escape(str(path))}: cannot read messages \(.+\); the log may be truncated or corrupted"))


def test_corrupted_mcap_chunk_fails(logs, capsys):
    from mcap.reader import make_reader

    path = logs.sensor_log("mcap", duration_s=0.5)
    with path.open("rb") as f:
        chunk = make_reader(f).get_summary().chunk_indexes[0]
    data = bytearray(path.read_bytes())
    mid = chunk.chunk_start_offset + chunk.chunk_length // 2
    data[mid : mid + 32] = b"\x55" * 32
    path.write_bytes(bytes(data))
    rc, _, err = run(capsys, "info", path, "--check")
    assert_one_line_error(rc, err, re.compile(rf"lio: error: {re.escape(str(path))}: .+truncated or corrupted"))


def test_empty_log(logs, capsys, write_format):
    path = logs.write(write_format, lambda w: w.add_topic("/imu", "sensor_msgs/msg/Imu"))
    rc, _, err = run(capsys, "info", path)
    assert_one_line_error(rc, err, f"lio: error: {path}: empty log (1 topic(s) but 0 messages); nothing to read, "
                                   "check the recording")


def test_cloud_with_zero_valid_points(logs, capsys):
    def cloud(t):
        arr = cloud_with("time", "<f4", K / 512.0)
        if t == logs.T0_NS + 100_000_000:
            arr["x"] = arr["y"] = arr["z"] = 0.0
        return arr

    path = logs.sensor_log("ros1", duration_s=0.3, cloud=cloud)
    rc, _, err = run(capsys, "info", path)
    assert rc == 0  # the first scan is fine; info reads only that one
    rc, _, err = run(capsys, "info", path, "--check")
    assert_one_line_error(rc, err, f"lio: error: {path}: /points: cloud at 1700000000.100000000 s has zero valid "
                                   f"points ({N} NaN/zero returns); drop such scans or check the driver")


def test_stamps_going_backwards(logs, capsys):
    def extra(w):
        w.add_topic("/imu_raw", "sensor_msgs/msg/Imu")
        for i, ms in enumerate([0, 10, 20, 5]):
            w.write("/imu_raw", logs.T0_NS + i * 600_000_000,
                    w.make.imu(logs.T0_NS + ms * 1_000_000, "imu", [0, 0, 0], [0, 0, 9.8]))

    path = logs.sensor_log("mcap", duration_s=0.3, extra=extra)
    rc, out, _ = run(capsys, "info", path, "--json")
    assert rc == 0
    rc, _, err = run(capsys, "info", path, "--check")
    assert_one_line_error(rc, err, f"lio: error: {path}: /imu_raw: header stamps going backwards "
                                   "(1700000000.005000000 s after 1700000000.020000000 s); fix the log's stamps or re-record")


def test_bad_format_option(logs, capsys):
    path = logs.sensor_log("ros1", duration_s=0.1)
    rc, _, err = run(capsys, "info", path, "--format", "rosbag")
    assert_one_line_error(rc, err, "lio: error: Invalid value for '--format': 'rosbag' is not one of 'ros1', 'ros2', "
                                   "'mcap'; see 'lio info --help'")


# ---- app-level flags ---------------------------------------------------------------------------------


def test_version(capsys):
    rc, out, _ = run(capsys, "--version")
    assert rc == 0 and out == f"lio {__version__}\n"


def test_help_has_examples(capsys):
    rc, out, _ = run(capsys, "--help")
    assert rc == 0 and "info" in out and "Exit codes" in out
    rc, out, _ = run(capsys, "info", "--help")
    assert rc == 0 and "Examples" in out and "lio info" in out and "--check" in out


def test_debug_shows_the_traceback(capsys, tmp_path):
    from lio_cli.errors import InputError

    with pytest.raises(InputError, match="no such file or folder"):
        main(["--debug", "info", str(tmp_path / "missing.bag")])


def test_usage_error_is_exit_2(capsys):
    rc, _, err = run(capsys, "info", "--no-such-option", "x")
    assert rc == 2 and "Traceback" not in err
    assert "No such option: --no-such-option" in err


def test_console_script_one_line_error_and_debug_traceback(tmp_path):
    lio = Path(sys.executable).parent / "lio"
    assert lio.exists(), "pip install . puts the lio console script beside the interpreter"
    missing = tmp_path / "missing.bag"
    res = subprocess.run([str(lio), "info", str(missing)], capture_output=True, text=True, timeout=60)
    assert res.returncode == 2 and res.stderr == f"lio: error: {missing}: no such file or folder\n"
    res = subprocess.run([str(lio), "--debug", "info", str(missing)], capture_output=True, text=True, timeout=60)
    assert res.returncode != 0 and "Traceback (most recent call last)" in res.stderr


def test_info_laserscan_topic(logs, capsys, write_format):
    def build(w):
        w.add_topic("/scan", "sensor_msgs/msg/LaserScan")
        for i in range(3):
            t = logs.T0_NS + i * 100_000_000
            w.write("/scan", t, w.make.laserscan(t, "laser", -1.0, 0.01, 1 / 512, 0.1, 0.1, 10.0,
                                                 np.r_[np.full(40, 2.0), np.inf, np.nan]))

    path = logs.write(write_format, build)
    rc, out, _ = run(capsys, "info", path, "--json")
    assert rc == 0
    (scan,) = json.loads(out)["scans"]
    assert (scan["beams"], scan["points"], scan["valid_points"], scan["frame_id"]) == (42, 42, 40, "laser")
    tc = scan["time_convention"]
    assert (tc["name"], tc["header_stamp_marks"]) == ("laserscan", "start")
    assert tc["scan_duration_s"] == pytest.approx(39 / 512, abs=1e-9)


def test_check_note_goes_to_stderr_and_quiet_silences_it(logs, capsys):
    path = logs.sensor_log("ros1", duration_s=0.2)
    rc, out, err = run(capsys, "info", path, "--check")
    assert rc == 0 and "/points" in out
    assert err == "check passed: 28 sensor messages decoded, stamps in order, clouds non-empty\n"
    rc, _, err = run(capsys, "info", path, "--check", "--quiet")
    assert rc == 0 and err == ""


def test_info_warns_about_a_contradictory_tf_static(logs, capsys):
    """A second /tf_static message giving base_link -> velodyne 0.5 m away from the chain through imu_link: info
    lists it, warns once naming the frames and the distance, and still exits 0 (it only describes); ``--check`` fails on it."""
    from lio_cli.geometry import make_pose

    def extra(w):
        T = logs.T_BASE_IMU @ logs.T_IMU_LIDAR @ make_pose(np.eye(3), np.array([0.5, 0.0, 0.0]))
        w.write("/tf_static", logs.T0_NS + 1, w.make.tf_message([
            w.make.transform_stamped(logs.T0_NS, "base_link", "velodyne", T)]))

    path = logs.sensor_log("ros1", duration_s=0.2, extra=extra)
    rc, out, err = run(capsys, "info", path)
    assert rc == 0
    assert err.strip() == (f"lio: warning: {path}: /tf_static contradicts itself: base_link -> velodyne disagrees "
                           "with base_link -> imu_link, imu_link -> velodyne by 0.500 m and 0.00 deg")
    assert "base_link -> velodyne" in out
    # --check checks: the contradiction fails it, exit 2, one line
    rc, _, err = run(capsys, "info", path, "--check")
    assert rc == 2
    assert err.strip() == (f"lio: error: {path}: /tf_static contradicts itself: base_link -> velodyne disagrees "
                           "with base_link -> imu_link, imu_link -> velodyne by 0.500 m and 0.00 deg")
