"""What issue 27's fusion matrix needs from `lio simulate`: a consumer GPS (slow metres of error, altitude
wander, a multipath jump, optimistic or absent covariance), wheel slip bursts, the rover (a ground robot on
uneven ground) and logs without LiDAR; each effect measured in the written log against the exact truth."""

from __future__ import annotations

import hashlib
import json

import numpy as np
import pytest

from lio_cli.cli.app import main
from lio_cli.geodesy import EnuFrame
from lio_cli.io.logs.reader import open_log
from lio_cli.simulation import build_scenario, output_paths, simulate

NS = 1_000_000_000
START_NS = 1_700_000_000 * NS
ORIGIN = (47.3769, 8.5417, 408.0)


def _stamp(msg) -> int:
    return msg.header.stamp.sec * NS + msg.header.stamp.nanosec


def _messages(out, topic):
    with open_log(out) as log:
        return [m for _, _, _, m in log.messages([topic])]


def _gps_errors(out, scenario, start="still"):
    """(stamps, ENU error of each valid fix against the true antenna position, the valid messages)."""
    fixes = [m for m in _messages(out, "/gps/fix") if m.status.status == 0]
    stamps = np.array([_stamp(m) for m in fixes])
    enu = EnuFrame(*ORIGIN).to_enu(np.array([m.latitude for m in fixes]), np.array([m.longitude for m in fixes]),
                                    np.array([m.altitude for m in fixes]))
    sc = build_scenario(scenario, start=start)
    st = sc.trajectory.state((stamps - START_NS) * 1e-9)
    antenna = st.position_m + st.R_world_base @ np.asarray(sc.gps_antenna_m)
    return stamps, enu - antenna, fixes


def test_consumer_gps_wanders_jumps_and_reports_an_optimistic_covariance(tmp_path):
    out = tmp_path / "g.mcap"
    simulate("rover", out, duration_s=60.0, seed=4, lidar=False, gps=True, gps_model="consumer", gps_origin=ORIGIN,
             gps_alt_wander_m=30.0, gps_jump_m=10.0, gps_outage_s=0.0, gps_invalid_fraction=0.0, gps_noise_m=(2.5, 0.3))
    truth = json.loads(output_paths(out)[1].read_text())["gps"]
    stamps, err, fixes = _gps_errors(out, "rover")
    t = (stamps - START_NS) * 1e-9
    # the altitude wanders slowly by the asked 30 m peak to peak: 2 s means of the up error span 30 +- 1 m
    # (the up noise is 0.3 m here), and it is smooth: the 2 s means change by under 2 m/s
    means = np.array([err[(t >= a) & (t < a + 2.0), 2].mean() for a in np.arange(0.0, 58.0, 0.2)])
    assert 29.0 < means.max() - means.min() < 31.0
    assert np.abs(means[10:] - means[:-10]).max() < 4.0
    assert truth["altitude_wander"]["peak_to_peak_m"] == 30.0
    # the multipath jump: every fix in its window shifted by the recorded 10 m offset (the slow error barely
    # moves over the 3 s either side, the white part averages over 15 fixes)
    jump = truth["multipath_jump"]
    assert np.linalg.norm(jump["offset_enu_m"]) == pytest.approx(10.0) and jump["offset_enu_m"][2] == 0.0
    inside = (stamps >= jump["start_ns"]) & (stamps < jump["end_ns"])
    assert inside.sum() == 25  # 5 s at 5 Hz, none invalid here or lost to the outage
    near = ((stamps >= jump["start_ns"] - 3 * NS) & (stamps < jump["start_ns"])) | \
           ((stamps >= jump["end_ns"]) & (stamps < jump["end_ns"] + 3 * NS))
    step = err[inside, :2].mean(axis=0) - err[near, :2].mean(axis=0)
    np.testing.assert_allclose(step, jump["offset_enu_m"][:2], atol=1.5)
    # horizontal error of metres, mostly slow like a real receiver's: the fix-to-fix jitter is the white tenth
    # of the variance (2.5 m * sqrt(0.1) per axis), the error itself metres
    calm = ~inside
    horiz_rms = np.sqrt(np.mean(np.sum(err[calm, :2] ** 2, axis=1)))
    jitter = np.diff(err[calm, :2], axis=0).std(axis=0) / np.sqrt(2.0)
    np.testing.assert_allclose(jitter, 2.5 * np.sqrt(0.1), rtol=0.2)
    assert 1.0 < horiz_rms < 8.0 and horiz_rms > 2.0 * jitter.max()
    # the covariance claims a third of the true sigmas (2.5 m, 1.5 m) and nothing of the wander
    for m in fixes:
        assert m.position_covariance_type == 2
        np.testing.assert_allclose(np.diag(np.reshape(m.position_covariance, (3, 3))),
                                   [(2.5 / 3) ** 2, (2.5 / 3) ** 2, 0.01], rtol=1e-12)
    assert truth["model"] == "consumer" and truth["covariance"] == "optimistic"


def test_gps_covariance_absent_and_the_standard_model_keeps_its_truth_keys(tmp_path):
    out = tmp_path / "a.mcap"
    simulate("corridor", out, duration_s=4.0, seed=1, lidar=False, gps=True, gps_covariance="absent",
             gps_invalid_fraction=0.0, gps_outage_s=0.0)
    fixes = _messages(out, "/gps/fix")
    assert len(fixes) == 21 and all(m.position_covariance_type == 0 for m in fixes)
    assert all(not any(m.position_covariance) and np.isfinite(m.latitude) for m in fixes)
    gps = json.loads(output_paths(out)[1].read_text())["gps"]
    assert gps["covariance"] == "absent" and gps["altitude_wander"] is None and gps["multipath_jump"] is None
    out2 = tmp_path / "s.mcap"
    simulate("corridor", out2, duration_s=4.0, seed=1, lidar=False, gps=True)
    assert "model" not in json.loads(output_paths(out2)[1].read_text())["gps"]


def test_slip_bursts_add_their_recorded_speed_error_to_exact_wheels(tmp_path):
    out = tmp_path / "w.mcap"
    simulate("rover", out, duration_s=30.0, seed=2, lidar=False, wheel_errors=False, wheel_slip_bursts=3)
    wheel = json.loads(output_paths(out)[1].read_text())["wheel"]
    bursts = wheel["slip_bursts"]
    assert wheel["slip"] is None and len(bursts) == 3
    msgs = _messages(out, "/wheel/odom")
    stamps = np.array([_stamp(m) for m in msgs])
    v_meas = np.array([m.twist.twist.linear.x for m in msgs])
    sc = build_scenario("rover")
    st = sc.trajectory.state((stamps - START_NS) * 1e-9)
    v = np.einsum("ni,ni->n", st.velocity_mps, st.R_world_base[:, :, 0])
    half_track = 0.5 * sc.wheels.baseline_m * st.omega_base_radps[:, 2]
    seen = np.zeros(len(stamps), bool)
    for b in bursts:
        assert 1.0 <= b["duration_s"] <= 2.5 and 0.1 <= b["left"] <= 0.4 and 0.1 <= b["right"] <= 0.4
        # the flat middle of the raised-cosine window: each wheel reads (1 + slip) x its ground speed
        core = (stamps >= b["start_ns"] + 0.1 * b["duration_s"] * NS) & (stamps <= b["end_ns"] - 0.1 * b["duration_s"] * NS)
        want = 0.5 * ((v + half_track) * (1 + b["right"]) + (v - half_track) * (1 + b["left"]))
        np.testing.assert_allclose(v_meas[core], want[core], atol=1e-9)
        assert (v_meas[core] - v[core]).mean() > 0.1 * v[core].mean()  # a speed error of 10-40 %
        seen |= (stamps >= b["start_ns"]) & (stamps <= b["end_ns"])
    np.testing.assert_allclose(v_meas[~seen], v[~seen], atol=1e-9)  # exact wheels elsewhere


def test_rover_is_a_ground_robot_on_uneven_ground():
    sc = build_scenario("rover", start="moving")
    st = sc.trajectory.state(np.arange(0.0, 120.0, 0.05))
    roll = np.degrees(np.arctan2(st.R_world_base[:, 2, 1], st.R_world_base[:, 2, 2]))
    pitch = np.degrees(-np.arcsin(st.R_world_base[:, 2, 0]))
    assert 1.5 < np.abs(roll).max() < 4.0 and 1.5 < np.abs(pitch).max() < 4.0  # terrain, not a flat floor
    travelled = np.linalg.norm(np.diff(st.position_m[:, :2], axis=0), axis=1).sum()
    assert np.ptp(st.position_m[:, 2]) < 0.15 and travelled > 150.0  # 2D motion, 1.5 m/s
    yaw = np.unwrap(np.arctan2(st.R_world_base[:, 1, 0], st.R_world_base[:, 0, 0]))
    assert np.ptp(yaw) > 1.5  # weaving and a corner: heading matters
    assert sc.wheels is not None and sc.lidar.beams == 16


def test_drone_flies_in_3d():
    sc = build_scenario("drone", start="moving")
    st = sc.trajectory.state(np.arange(0.0, 60.0, 0.05))
    z = st.position_m[:, 2]
    assert 1.4 < z.min() and z.max() < 10.6 and np.ptp(z) > 5.0  # climbs and sinks by metres in a minute
    assert np.abs(st.velocity_mps[:, 2]).max() > 0.5
    v_base = np.einsum("nji,nj->ni", st.R_world_base, st.velocity_mps)
    assert np.abs(v_base[:, 1]).max() > 1.0  # flies sideways: no wheel could measure that
    assert sc.wheels is None and sc.lidar.beams == 16


def test_no_lidar_leaves_every_other_message_byte_identical(tmp_path):
    args = dict(duration_s=2.0, seed=9, columns=64, gps=True, gps_model="consumer", start="moving",
                imu_rotation_deg=(180.0, 0.0, 90.0), imu_lever_arm_m=(0.3, -0.2, 0.25), wheel_slip_bursts=1)
    full, cheap = tmp_path / "full.mcap", tmp_path / "cheap.mcap"
    simulate("rover", full, **args)
    simulate("rover", cheap, lidar=False, **args)

    def raw(out):
        with open_log(out) as log:
            return [(t, topic, bytes(data)) for topic, _, t, data in log.raw_messages() if topic != "/points"]

    assert raw(full) == raw(cheap)
    with open_log(cheap) as log:
        assert "/points" not in {c.topic for c in log.connections}
    assert json.loads(output_paths(cheap)[1].read_text())["lidar"] is None


def test_same_arguments_same_bytes(tmp_path):
    argv = ["simulate", "rover", "--duration", "2", "--columns", "64", "--seed", "3", "--start", "moving",
            "--gps-model", "consumer", "--gps-jump", "5", "--wheel-slip-bursts", "2", "--wheel-radius-scale",
            "1.03,1.03", "--quiet"]
    digests = []
    for name in ("a.mcap", "b.mcap"):
        assert main([*argv[:2], str(tmp_path / name), *argv[2:]]) == 0
        digests.append([hashlib.sha256(p.read_bytes()).hexdigest()
                        for p in (tmp_path / name, *output_paths(tmp_path / name))])
    assert digests[0] == digests[1]


@pytest.mark.parametrize("scenario, argv, message", [
    ("rover", ("--gps-model", "rtk"), "Invalid value for '--gps-model': 'rtk' is not one of 'standard', 'consumer'; "
                                      "see 'lio simulate --help'"),
    ("rover", ("--gps-jump", "-1"), "--gps-jump must be within 0..200 m (got -1.0)"),
    ("rover", ("--gps-alt-wander", "500"), "--gps-alt-wander must be within 0..200 m (got 500.0)"),
    ("handheld", ("--wheel-slip-bursts", "2"),
     "--wheel-slip-bursts needs wheels (drive, corridor, planar or rover, without --no-wheel)"),
    ("drone", ("--wheel",), "--wheel: the drone scenario has no wheels"),
    ("static", ("--no-lidar",), "--no-lidar does not apply to the static scenario (an IMU at rest, no LiDAR, wheels "
                                "or GPS)"),
])
def test_bad_options_exit_2_with_one_line(tmp_path, capsys, monkeypatch, scenario, argv, message):
    assert_refused(tmp_path, capsys, monkeypatch, ["simulate", scenario, "x.bag", "--duration", "2", *argv], message)


def assert_refused(tmp_path, capsys, monkeypatch, argv: list[str], message: str) -> None:
    """``lio ARGV`` run in ``tmp_path``: exit 2, ``message`` as the one line on stderr, nothing written."""
    monkeypatch.chdir(tmp_path)
    rc = main(argv)
    out, err = capsys.readouterr()
    assert (rc, out, err) == (2, "", f"lio: error: {message}\n")
    assert not any(tmp_path.iterdir())
