"""A car already moving, wheels with a 3 % radius scale and slip bursts, IMU, nothing else: a flat road must
get the planar filter. The estimator choice took the slips' wheel accelerations (metres per second in a
fraction of one, which the IMU never felt) for the ground tilting 10 deg, chose the 3D filter, and that
drifted 10 m where wheel speed + gyro dead reckoning stays near 1 m. The accelerometer then finds the slips and
the wheel scale before the planar filter runs (core/fuse/wheel_slip.py)."""

from __future__ import annotations

import json
import re

from lio_cli.config.fuse import FuseConfig
from lio_cli.jobs.fuse.job import FuseJob, run_fuse
from lio_cli.jobs.fuse.summary import source_summary
from lio_cli.simulation.run import simulate

from .test_simulated import _ate, _dead_reckoning

WHEEL_RATIO = 0.05  # fused ATE vs the wheels' own dead reckoning (measured 0.015; 0.14 without the slip check)


def test_slipping_wheels_on_a_flat_road_get_the_planar_filter(tmp_path):
    log = tmp_path / "car.mcap"
    simulate("drive", log, duration_s=30.0, seed=7, start="moving", lidar=False, wheel_errors=False,
             wheel_radius_scale=(1.03, 1.03), wheel_slip_bursts=3)
    run = run_fuse(FuseJob(log, FuseConfig(rate_hz=20.0)))
    assert run.metrics["estimator"] == "planar", run.metrics["estimator_reason"]
    assert run.metrics["core"]["estimator_evidence"]["slip_windows"] >= 3
    assert _ate(log, run.trajectory) < WHEEL_RATIO * _dead_reckoning(log)
    check = run.metrics["core"]["wheel_check"]
    assert check["slips"] == 3 and check["scale_applied"] and abs(check["scale"] - 1.03) < 0.01
    wheel = run.metrics["sources"]["wheel"]  # bridged speeds are replaced, not dropped: no speed rejection
    slip = wheel["handled"]["slip_bridged"]
    assert slip["count"] == check["bridged"] > 0 and "slip" in slip["what"] and "IMU" in slip["what"]
    assert "slip" not in wheel["rejected"], wheel["summary"]
    # the wheels' yaw rate, its 3 % scale divided out, enters beside the gyro; a slip's yaw rates are left out
    yaw = run.metrics["core"]["wheel_yaw_check"]
    assert yaw["used"] and yaw["scale_applied"] and abs(yaw["scale_off"] - (1 - 1 / 1.03)) < 0.002, yaw
    assert wheel["rejected"]["yaw_slip"]["count"] == yaw["far_samples"] > 0
    assert f", {check['bridged']} slip bridged by the IMU, " in wheel["summary"], wheel["summary"]


def test_the_summary_line_counts_bridged_speeds_as_used_not_rejected():
    line = source_summary("wheel", 1501, 0, {"wheel_speed": {"updates": 1501, "outlier": 0}}, {},
                          {"slip_bridged": 337, "scale_corrected": 1501})
    assert line == "wheel: 1501 speed updates, 337 slip bridged by the IMU"


LONG_S = 150.0  # five stretches of the tilt's re-anchoring (tilt_track.SEGMENT_S)
LONG_WHEEL_RATIO = 0.1  # fused ATE vs the wheels' own dead reckoning (measured 0.03; 0.24 with gravity carried)


def test_a_long_drive_measures_the_wheel_scale_and_bridges_every_slip(tmp_path):
    # gravity carried by the gyro from the first second tilted with its bias: scale 1.0445 +- 0.0133 unmeasured,
    # a slip window from 73 s to the end, both slips left in
    log = tmp_path / "rover.mcap"
    simulate("rover", log, duration_s=LONG_S, seed=7, lidar=False, wheel_errors=False,
             wheel_radius_scale=(1.03, 1.03), wheel_slip_bursts=3)
    truth = json.loads(log.with_suffix(".truth.json").read_text())["wheel"]
    run = run_fuse(FuseJob(log, FuseConfig(rate_hz=20.0)))
    check = run.metrics["core"]["wheel_check"]
    assert abs(check["scale"] - truth["radius_scale_left"]) <= check["scale_sigma"] < 0.005, check
    assert check["scale_applied"] and check["slips"] == len(truth["slip_bursts"]) == 3 and check["left_in"] == 0
    for (a, b), burst in zip(check["windows_s"], truth["slip_bursts"]):  # each window around its burst, no longer
        assert a <= burst["start_s"] and burst["start_s"] + burst["duration_s"] <= b <= a + 2 * burst["duration_s"]
    slip = run.metrics["sources"]["wheel"]["handled"]["slip_bridged"]
    assert slip["count"] == check["bridged"] > 0, slip
    assert check["why"] == (f"wheel scale {check['scale']:.4f} +- {check['scale_sigma']:.4f} (applied); "
                            "3 slip(s) bridged by the IMU")
    assert _ate(log, run.trajectory) < LONG_WHEEL_RATIO * _dead_reckoning(log)


def test_an_imu_clock_offset_that_spoils_the_check_is_named_with_the_offset_to_give(tmp_path):
    # IMU stamps 0.5 s late: every wheel speed change looked like a slip, "1 clean 1 s stretches", no hint why
    log = tmp_path / "rover.mcap"
    simulate("rover", log, duration_s=30.0, seed=7, lidar=False, imu_time_offset_s=-0.5)
    check = run_fuse(FuseJob(log, FuseConfig(rate_hz=20.0))).metrics["core"]["wheel_check"]
    assert check["scale"] is None and check["bridged"] == 0
    assert re.fullmatch(r"1 clean 1 s stretches \(no slip window, no IMU gap\), fewer than 12: scale not measured; "
                        r"the wheel speed's changes match the accelerometer's \+0\.50 s later in its stamps "
                        r"\(correlation 0\.8\d, 0\.[0-6]\d unshifted\): a clock offset\? Try --imu-time-offset "
                        r"-0\.50 if the IMU is off, --time-offset wheel=0\.50 if the wheels are", check["why"]), \
        check["why"]
