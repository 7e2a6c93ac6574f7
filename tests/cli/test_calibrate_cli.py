"""``lio calibrate`` from the command line: the YAML odom reads, the table, the bad-input lines (exit 2,
nothing written)."""

import json
from pathlib import Path

import numpy as np
import pytest

from lio_cli.cli.app import main
from lio_cli.config import load_calibration
from lio_cli.geometry import so3_log
from lio_cli.io.logs.writer import LogWriter
from lio_cli.simulation.run import simulate

T0 = 1_700_000_000 * 10**9
G = 9.81


@pytest.fixture(scope="module")
def walk(tmp_path_factory):
    root = tmp_path_factory.mktemp("walk")
    return simulate("handheld", root / "walk.bag", "ros1", duration_s=8.0, seed=7, columns=512,
                    imu_time_offset_s=0.04, imu_rotation_deg=(0.0, 10.0, 45.0), imu_lever_arm_m=(0.2, 0.1, 0.0),
                    tf_static=False)


def room_cloud(n_az: int = 360, beams: int = 16) -> np.ndarray:
    """A box room 12 x 9 x 3 m seen from (1, 0.5, 1.2) inside it: structured x, y, z, time (s, relative)."""
    az = np.repeat(np.linspace(0, 2 * np.pi, n_az, endpoint=False), beams)
    el = np.tile(np.radians(np.linspace(-15, 15, beams)), n_az)
    d = np.stack([np.cos(el) * np.cos(az), np.cos(el) * np.sin(az), np.sin(el)], axis=1)
    o = np.array([1.0, 0.5, 1.2])
    lo, hi = np.array([-6.0, -4.5, 0.0]), np.array([6.0, 4.5, 3.0])
    with np.errstate(divide="ignore"):
        t = np.where(d > 0, (hi - o) / d, (lo - o) / d)
    r = np.min(np.where(np.isfinite(t) & (t > 0), t, np.inf), axis=1)
    xyz = d * r[:, None]
    # a pillar and a shelf make the room's walls distinguishable
    arr = np.zeros(len(xyz), dtype=[("x", "<f4"), ("y", "<f4"), ("z", "<f4"), ("time", "<f4")])
    arr["x"], arr["y"], arr["z"] = xyz.T
    arr["time"] = np.repeat(np.arange(n_az), beams) / n_az * 0.1
    return arr


def static_log(path: Path, *, imu: bool = True, imu_clock_shift_ns: int = 0, seconds: float = 6.0,
               lidar: bool = True, turning: bool = False) -> Path:
    """A platform standing still in a room (or, ``turning``, an IMU spinning) with LiDAR and IMU; IMU header
    stamps shifted by ``imu_clock_shift_ns`` against their record times (another clock)."""
    rng = np.random.default_rng(1)
    cloud = room_cloud()
    with LogWriter(path, "ros1") as w:
        m = w.make
        if lidar:
            w.add_topic("/points", "sensor_msgs/msg/PointCloud2")
        if imu:
            w.add_topic("/imu", "sensor_msgs/msg/Imu")
        end = T0 + int(seconds * 1e9)
        if lidar:
            for t in range(T0, end, 100_000_000):
                w.write("/points", t + 100_000_000, m.pointcloud2(t, "lidar", cloud))
        if imu:
            for t in range(T0, end, 5_000_000):
                wz = 2.0 * np.sin(2 * np.pi * (t - T0) * 1e-9) if turning else 0.0
                gyro = rng.normal(0, 1e-3, 3) + [0, 0, wz]
                acc = rng.normal(0, 1e-2, 3) + [0, 0, G]
                w.write("/imu", t + 1_000_000, m.imu(t + imu_clock_shift_ns, "imu", gyro, acc))
    return path


def run(args, capsys):
    rc = main(["calibrate", *map(str, args)])
    cap = capsys.readouterr()
    return rc, cap.out, cap.err


def one_error(args, capsys, folder: Path) -> str:
    before = sorted(p.name for p in folder.iterdir())
    rc, out, err = run(args, capsys)
    assert rc == 2, err
    assert len(err.strip().splitlines()) == 1, err
    assert sorted(p.name for p in folder.iterdir()) == before  # nothing written
    return err.strip()


@pytest.fixture(scope="module")
def walk_run(walk, tmp_path_factory):
    out = tmp_path_factory.mktemp("out") / "walk.calib.yaml"
    rc = main(["calibrate", str(walk.log_path), "-o", str(out), "--json"])
    return rc, out


def test_the_yaml_round_trips_into_odom_calib(walk, walk_run, tmp_path, capsys):
    rc, out = walk_run
    assert rc == 0
    cal = load_calibration(out)
    t = json.loads(Path(walk.truth_path).read_text())
    assert abs(1e3 * (cal.imu_time_offset_s - t["imu"]["imu_time_offset_s"])) < 2.0
    text = out.read_text()
    assert text.startswith("# lio calibrate: T_base_imu / T_base_lidar map sensor points into the base frame")
    for key in ("T_base_imu:", "T_base_lidar:", "imu_time_offset_s:", "imu_time_offset_sigma_s:", "gyro_bias_radps:",
                "T_base_imu_rotation_sigma_rad:", "imu_noise:"):
        assert key in text
    # odom reads it: the same log (no /tf_static) with the estimated extrinsics and clock offset
    tum = tmp_path / "walk.tum"
    assert main(["odom", str(walk.log_path), "--calib", str(out), "-o", str(tum), "--gt", str(walk.gt_path),
                 "--json", "-q"]) == 0
    m = json.loads(capsys.readouterr().out)
    assert m["extrinsics"]["T_base_imu"] == "--calib"
    assert m["imu_time_offset"]["calibration_s"] == cal.imu_time_offset_s
    assert m["accuracy"]["ate_trans_rmse_m"] < 0.2


def test_json_table_and_metrics(walk_run, capsys):
    rc, out = walk_run
    metrics = json.loads(out.with_name("walk.calib.metrics.json").read_text())
    names = [r["quantity"] for r in metrics["table"]]
    assert names[:7] == ["T_base_imu rotation roll (x)", "T_base_imu rotation pitch (y)", "T_base_imu rotation yaw (z)",
                         "T_base_imu translation x", "T_base_imu translation y", "T_base_imu translation z",
                         "imu_time_offset_s"]
    assert metrics["reference"] is None and all(r["diff"] is None for r in metrics["table"])
    assert metrics["conventions"]["imu_time_offset_s"] == "added to IMU stamps to put them on the LiDAR's clock"


def test_stderr_table_against_a_given_calib_in_degrees_cm_and_ms(walk, tmp_path, capsys):
    prior = tmp_path / "prior.yaml"
    prior.write_text("T_base_imu: [[1,0,0,0.2],[0,1,0,0.1],[0,0,1,0],[0,0,0,1]]\nimu_time_offset_s: -0.03\n")
    out = tmp_path / "c.yaml"
    rc, _, err = run([walk.log_path, "-o", out, "--calib", prior], capsys)
    assert rc == 0, err
    lines = err.splitlines()
    head = next(i for i, line in enumerate(lines) if line.startswith("quantity"))
    assert lines[head].split() == ["quantity", "value", "1-sigma", "minus", "--calib", "unit"]
    row = {line.rsplit(None, 4)[0].strip(): line.split() for line in lines[head + 1: head + 8]}
    off = load_calibration(out).imu_time_offset_s
    ms = row["imu_time_offset_s"]
    assert ms[-1] == "ms" and float(ms[-2]) == pytest.approx(1e3 * (off + 0.03), abs=1e-3)
    yaw = row["T_base_imu rotation yaw (z)"]
    assert yaw[-1] == "deg" and abs(float(yaw[-2]) - 45.0) < 5.0  # against an identity prior
    assert row["T_base_imu translation x"][-1] == "cm"
    assert "not estimated: the wheel odometry scales: the log has no wheel odometry" in lines
    assert lines[-1].startswith(f"wrote {out}, {out.with_name('c.calib.metrics.json')}, "
                                f"{out.with_name('c.calib.config.yaml')};")


def test_the_default_output_is_the_log_stem_in_the_current_folder(walk, tmp_path, capsys, monkeypatch):
    monkeypatch.chdir(tmp_path)
    rc, _, err = run([walk.log_path, "-q"], capsys)
    assert rc == 0, err
    assert sorted(p.name for p in tmp_path.iterdir()) == ["walk.calib.config.yaml", "walk.calib.metrics.json",
                                                          "walk.calib.yaml"]
    lines = err.splitlines()  # -q: only what was not estimated
    assert "not estimated: the wheel odometry scales: the log has no wheel odometry" in lines
    assert all(line.startswith("not estimated: ") for line in lines)
    err = one_error([walk.log_path, "-q"], capsys, tmp_path)
    assert err == "lio: error: walk.calib.yaml: already exists; pass --force to overwrite it"


def test_dash_output_prints_the_yaml_on_stdout_and_writes_nothing(walk, walk_run, tmp_path, capsys, monkeypatch):
    """-o - wrote three files named '-', '-.metrics.json' and '-.config.yaml' into the current folder."""
    monkeypatch.chdir(tmp_path)
    rc, out, err = run([walk.log_path, "-o", "-"], capsys)
    assert rc == 0, err
    assert list(tmp_path.iterdir()) == []
    assert out.startswith("# lio calibrate: T_base_imu / T_base_lidar map sensor points into the base frame")
    (tmp_path.parent / "dash.yaml").write_text(out)
    got, want = load_calibration(tmp_path.parent / "dash.yaml"), load_calibration(walk_run[1])
    np.testing.assert_allclose(got.matrix("T_base_imu"), want.matrix("T_base_imu"), atol=1e-6)
    assert err.splitlines()[-1].startswith("wrote the calibration to stdout;")
    err = one_error([walk.log_path, "-o", "-", "--json"], capsys, tmp_path)
    assert err == "lio: error: -o - and --json both write to stdout; choose one"


def test_no_imu(tmp_path, capsys):
    log = static_log(tmp_path / "noimu.bag", imu=False)
    err = one_error([log, "-o", tmp_path / "x.yaml"], capsys, tmp_path)
    assert err == (f"lio: error: {log}: no IMU topic (sensor_msgs/Imu): lio calibrate calibrates an IMU (against the "
                   "LiDAR and the wheels); name one with --imu-topic")


def test_a_still_platform_gives_its_imu_at_rest_and_names_the_rest(tmp_path, capsys):
    """Standing still: the IMU at rest is measured (exit 0), and the mounting's tilt from gravity against the floor
    where it is sharp enough; the clock offset and the other axes are named as not estimated, with the motion that
    would show them."""
    log, out = static_log(tmp_path / "still.bag"), tmp_path / "x.yaml"
    rc, _, err = run([log, "-o", out], capsys)
    assert rc == 0, err
    lines = err.splitlines()
    offset = next(line for line in lines if line.startswith("not estimated: the LiDAR-IMU clock offset: "))
    assert offset.startswith("not estimated: the LiDAR-IMU clock offset: too little rotation to time the IMU against "
                             "the LiDAR: the trajectory turns at most ")
    assert offset.endswith("swing the sensor back and forth (yaw or roll sweeps of +-30 deg at about 1 Hz) for 10-20 s; "
                           "on a vehicle, drive a slalom; the other estimates use +0.000 ms and the YAML holds none "
                           "(give it with --imu-time-offset SECONDS or imu_time_offset_s in --calib if it is known)")
    # at rest gravity against the floor gives the tilt; the room's floor pins the pitch, not the roll, to 1 deg
    assert ("not estimated: the mounting's rotation about the LiDAR x axis: hand-eye could not use the rotations; "
            "gravity against the ground at rest gives it to 1-sigma ") in err
    assert ("not estimated: the mounting's rotation about the LiDAR z axis: hand-eye could not use the rotations; "
            "gravity and the ground at rest give the roll and pitch, not the rotation about the vertical: speed up "
            "and brake (with wheel odometry) to show it") in err
    text = out.read_text()
    assert "\nimu_time_offset_s" not in text and "\ngyro_bias_radps:" in text
    assert "# - imu_time_offset_s: too little rotation to time the IMU" in text
    cal = load_calibration(out)
    pitch_err = np.degrees(np.arcsin(np.asarray(cal.T_base_imu)[0, 2]))  # the IMU is mounted level
    assert abs(pitch_err) < 0.3 and np.degrees(cal.T_base_imu_rotation_sigma_rad[1]) < 1.0
    m = json.loads(out.with_name("x.calib.metrics.json").read_text())
    assert set(m["not_estimated"]) == {"imu_time_offset_s", "rotation_x", "rotation_z", "lever_arm", "wheel_scales",
                                       "T_base_lidar"}
    assert "imu_time_offset_s" not in m["calibration"] and "gyro_bias_sigma_radps" in m["calibration"]


@pytest.mark.parametrize("how", ["flag", "calib"])
def test_a_given_clock_offset_is_kept_where_the_motion_cannot_time_the_imu(tmp_path, capsys, how):
    """The offset given (even 0, which a --calib holding nothing else would otherwise look like no --calib at
    all) is kept, written without a 1-sigma, and said so."""
    log, out = static_log(tmp_path / "still.bag"), tmp_path / "x.yaml"
    if how == "flag":
        extra = ["--imu-time-offset", "0.004"]
    else:
        (tmp_path / "offset.yaml").write_text("imu_time_offset_s: 0.004\n")
        extra = ["--calib", tmp_path / "offset.yaml"]
    rc, _, err = run([log, "-o", out, *extra], capsys)
    assert rc == 0, err
    assert any(line.startswith("not estimated: the LiDAR-IMU clock offset: too little rotation") and
               line.endswith("; kept as given (+4.000 ms)") for line in err.splitlines()), err
    cal = load_calibration(out)
    assert cal.imu_time_offset_s == 0.004 and cal.imu_time_offset_sigma_s is None


def test_nothing_estimable_is_exit_2_naming_each_reason(tmp_path, capsys):
    """A car already cruising (never at rest) for 5 s, nearly straight, no wheels: nothing to measure."""
    sim = simulate("drive", tmp_path / "mv.bag", "ros1", duration_s=5.0, beams=16, columns=256, start="moving",
                   wheel=False)
    log = sim.log_path
    err = one_error([log, "-o", tmp_path / "x.yaml"], capsys, tmp_path)
    assert err.startswith(f"lio: error: {log}: nothing could be estimated: the IMU at rest (accelerometer bias along "
                          "gravity, noise densities): no still stretch of 1 s in the IMU data")
    for part in ("; the LiDAR-IMU clock offset: too little rotation to time the IMU against the LiDAR",
                 "; the IMU's mounting rotation (T_base_imu): too little rotation to estimate the LiDAR-IMU rotation",
                 "; the wheel odometry scales: the log has no wheel odometry"):
        assert part in err


def test_clock_mismatch(tmp_path, capsys):
    log = static_log(tmp_path / "clocks.bag", imu_clock_shift_ns=-3_000_000_000)
    err = one_error([log, "-o", tmp_path / "x.yaml"], capsys, tmp_path)
    assert err == (f"lio: error: {log}: /imu and /points are stamped on different clocks (/imu from "
                   "1699999997.000 s, /points from 1700000000.000 s: 2.901 s apart beyond their recording times); if /imu "
                   "runs on a shifted clock give --imu-time-offset 2.901")
    rc, _, err = run([log, "-o", tmp_path / "x.yaml", "--imu-time-offset", "2.901"], capsys)
    assert rc == 0, err  # joined: the IMU at rest is measured
    assert "kept as given (+2901.000 ms)" in err


def test_a_still_interval_where_the_platform_moves_says_where(walk, tmp_path, capsys):
    err = one_error([walk.log_path, "-o", tmp_path / "x.yaml", "--still", "3:5"], capsys, tmp_path)
    assert err.startswith(f"lio: error: {walk.log_path}: --still 3:5 is not a still stretch: the IMU moves during 3.0-")
    assert err.endswith("(s after its first stamp); name an interval where the platform stands still, or leave --still "
                        "out to find one")


def test_an_imu_only_log_that_never_rests(tmp_path, capsys):
    log = static_log(tmp_path / "spin.bag", lidar=False, turning=True)
    err = one_error([log, "-o", tmp_path / "x.yaml"], capsys, tmp_path)
    assert err.startswith(f"lio: error: {log}: no still stretch of 1 s in the IMU data: it moves during 0.0-")
    assert err.endswith("(the log has no LiDAR: the IMU at rest is all there is to calibrate)")


def test_allan_files_need_allan_and_a_bad_still_is_a_usage_error(walk, tmp_path, capsys):
    err = one_error([walk.log_path, "-o", tmp_path / "x.yaml", "--kalibr", tmp_path / "imu.yaml"], capsys, tmp_path)
    assert err == "lio: error: --plot and --kalibr write the Allan variance results: give --allan too"
    # one path for two outputs: the Kalibr file silently replaced the calibration; refused before any work
    err = one_error([walk.log_path, "-o", tmp_path / "x.yaml", "--allan", "--kalibr", tmp_path / "x.yaml"], capsys,
                    tmp_path)
    assert err == (f"lio: error: {tmp_path / 'x.yaml'}: would be both the calibration (-o) and the Kalibr imu.yaml "
                   "(--kalibr); give each output its own path")
    (tmp_path / "plots").write_text("")
    err = one_error([walk.log_path, "-o", tmp_path / "x.yaml", "--allan", "--plot", tmp_path / "plots"], capsys,
                    tmp_path)
    assert err == f"lio: error: {tmp_path / 'plots'}: exists and is not a folder"
    err = one_error([walk.log_path, "-o", tmp_path / "x.yaml", "--still", "5:2"], capsys, tmp_path)
    assert err == ("lio: error: options: still: '5:2' is not START:END in seconds after the first IMU sample with "
                   "0 <= START < END (e.g. 0:2.5)")


def test_a_static_imu_log_gives_allan_kalibr_and_plot(tmp_path, capsys):
    sim = simulate("static", tmp_path / "imu.mcap", "mcap", duration_s=600.0, seed=2)
    t = json.loads(Path(sim.truth_path).read_text())
    out, kal, plots = tmp_path / "imu.calib.yaml", tmp_path / "kalibr_imu.yaml", tmp_path / "plots"
    rc, _, err = run([sim.log_path, "-o", out, "--allan", "--kalibr", kal, "--plot", plots], capsys)
    assert rc == 0, err
    noise = load_calibration(out).imu_noise
    assert noise.source.startswith("Allan variance of 600 s")
    # 10 minutes pin the white noise (the random walk needs hours: the benchmark checks it on 2 h)
    assert noise.gyro_noise_radps == pytest.approx(t["imu"]["gyro_noise_density"], rel=0.1)
    assert noise.accel_noise_mps2 == pytest.approx(t["imu"]["accel_noise_density"], rel=0.1)
    assert "gyroscope_noise_density:" in kal.read_text()
    assert (plots / "allan_deviation.png").read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    assert "not estimated: the LiDAR-IMU time offset, rotation and translation: the log has no LiDAR topic" in err


def test_a_real_vehicle_that_never_rests_is_told_where_it_moves(real_logs, tmp_path, capsys):
    """robot_localization's test1.bag: a ground vehicle moving from 0.9 s to its end with pauses under a second.
    The message once listed four blips of its first two seconds "and 5 more", hiding 130 s of motion."""
    log = real_logs / "groovy_imu_wheel_stereo" / "groovy.bag"
    err = one_error([log, "-o", tmp_path / "x.yaml"], capsys, tmp_path)
    assert err == (f"lio: error: {log}: no still stretch of 1 s in the IMU data: it moves during 0.9-133.1 s (s after "
                   "its first stamp, pauses shorter than 1 s included; the longest still stretch lasts 0.67 s); record "
                   "a few seconds standing still or name a still interval (the log has no LiDAR: the IMU at rest is "
                   "all there is to calibrate)")


@pytest.fixture(scope="module")
def car(tmp_path_factory):
    """8 s of a car in town with gentle turns: its IMU yawed 20 deg, 10 ms late, wheels 3 % large."""
    root = tmp_path_factory.mktemp("car")
    sim = simulate("drive", root / "car.bag", "ros1", duration_s=8.0, beams=16, columns=512,
                   imu_rotation_deg=(0.0, 0.0, 20.0), imu_time_offset_s=0.01, wheel_radius_scale=(1.03, 1.03))
    out = root / "car.calib.yaml"
    rc = main(["calibrate", str(sim.log_path), "-o", str(out), "-q"])
    return sim, rc, out


def test_a_car_with_gentle_turns_gets_its_wheels_and_names_its_clock_offset(car):
    """Exit 0: the wheel scales need no clock offset and are within 3 sigma of the truth; the clock offset the
    gentle turns cannot time is left out of the YAML and named in it and in metrics."""
    sim, rc, out = car
    assert rc == 0
    t = json.loads(Path(sim.truth_path).read_text())["wheel"]
    s_v = 0.5 * (t["radius_scale_left"] + t["radius_scale_right"])
    w = load_calibration(out).wheel
    assert abs(w.speed_scale - s_v) <= 3 * w.speed_scale_sigma and w.speed_scale_sigma < 0.01
    assert abs(w.yaw_rate_scale - s_v / t["baseline_scale"]) <= 3 * w.yaw_rate_scale_sigma
    text = out.read_text()
    assert "\nimu_time_offset_s" not in text and "\nwheel:" in text and "\nT_base_imu_rotation_sigma_rad:" in text
    m = json.loads(out.with_name("car.calib.metrics.json").read_text())
    why = m["not_estimated"]
    assert why["imu_time_offset_s"].startswith("too little rotation to time the IMU against the LiDAR: the trajectory "
                                               "turns at most ")
    assert "on a vehicle, drive a slalom" in why["imu_time_offset_s"]
    assert why["rotation_z"].startswith("not observable from rotations (1-sigma ")
    assert "as a ground vehicle turning about the vertical does" in why["rotation_z"]
    for key in why:
        assert f"\n# - {key}: " in text


def test_odom_reads_a_partial_calibration(car, tmp_path, capsys):
    sim, _, out = car
    tum = tmp_path / "car.tum"
    assert main(["odom", str(sim.log_path), "--calib", str(out), "--prefer-calib", "-o", str(tum), "--json",
                 "-q"]) == 0
    m = json.loads(capsys.readouterr().out)
    assert m["extrinsics"]["T_base_imu"].startswith("--calib (--prefer-calib")
    assert len(tum.read_text().splitlines()) > 50


@pytest.fixture(scope="module")
def corridor(tmp_path_factory):
    root = tmp_path_factory.mktemp("corridor")
    return simulate("corridor", root / "corridor.bag", "ros1", duration_s=10.0, beams=16, columns=512,
                    wheel_radius_scale=(1.03, 1.03))


@pytest.mark.parametrize("offset", [None, "0.0"])
def test_a_corridor_robot_gets_roll_pitch_and_imu_with_or_without_a_clock_offset(corridor, tmp_path, capsys, offset):
    """Along a featureless corridor the LiDAR cannot see the distance travelled, so the wheels are not measured
    either; the IMU at rest and the mounting's roll and pitch are (exit 0), the offset given kept."""
    out = tmp_path / "c.yaml"
    rc, _, err = run([corridor.log_path, "-o", out, *(["--imu-time-offset", offset] if offset else [])], capsys)
    assert rc == 0, err
    cal = load_calibration(out)
    m = json.loads(out.with_name("c.calib.metrics.json").read_text())
    assert {"imu_time_offset_s", "rotation_z", "lever_arm", "wheel_scales"} <= set(m["not_estimated"])
    assert ("imu_time_offset_s" in m["calibration"]) == (offset is not None) and cal.imu_time_offset_sigma_s is None
    assert m["not_estimated"]["wheel_scales"].startswith("wheel scales: the platform moved ")
    T, Tt = cal.matrix("T_base_imu"), np.array(json.loads(Path(corridor.truth_path).read_text())["T_base_imu"])
    err_deg = np.degrees(so3_log(T[:3, :3] @ Tt[:3, :3].T))
    sig_deg = np.degrees(cal.T_base_imu_rotation_sigma_rad)
    assert (np.abs(err_deg[:2]) <= 3 * sig_deg[:2] + 0.1).all(), (err_deg, sig_deg)
