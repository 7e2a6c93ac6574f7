"""`lio odom --calib`: the calibration's wheel scales applied to the wheel odometry it joins to the prediction, and
an IMU mounting the calibration could not measure named."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from lio_cli.config.odom import OdomConfig
from lio_cli.core.odometry.loop import LioOdometry
from lio_cli.io.logs.reader import open_log
from lio_cli.io.sensors.stream import SensorStream
from lio_cli.jobs.odom.job import OdomJob, run_odom
from lio_cli.model.calibration import Calibration, WheelCalibration
from lio_cli.simulation.run import simulate


@pytest.mark.parametrize("topic", [None, "/wheel/odom", "/rear/odom"])
def test_wheel_records_reach_the_odometry_scaled(tmp_path, monkeypatch, topic):
    """Scales apply to the topic they were measured on (or to any when the calibration names none)."""
    sim = simulate("planar", tmp_path / "rover.mcap", "mcap", duration_s=6.0, seed=2, columns=360,
                   wheel_radius_scale=(1.03, 1.04), wheel_baseline_scale=1.05)
    seen = []
    original = LioOdometry.add_wheel
    monkeypatch.setattr(LioOdometry, "add_wheel", lambda self, rec: (seen.append(rec), original(self, rec))[1])
    wheel = WheelCalibration(topic=topic, speed_scale=1.035, speed_scale_sigma=0.001, yaw_rate_scale=0.9857, yaw_rate_scale_sigma=0.001)
    res = run_odom(OdomJob(sim.log_path, config=OdomConfig(calibration=Calibration(wheel=wheel))))
    applied = topic != "/rear/odom"
    assert ("wheel odometry /wheel/odom scaled by --calib (speed x1.035, yaw rate x0.9857)" in res.notes) == applied
    assert ("the wheel scales of --calib were measured on /rear/odom, not /wheel/odom: not applied" in res.notes) \
        == (not applied)
    sv, sw = (1.035, 0.9857) if applied else (1.0, 1.0)
    with open_log(sim.log_path) as reader:
        raw = {r.stamp_ns: r.data for r in SensorStream(reader, {"wheel": "/wheel/odom"}) if r.kind == "wheel"}
    assert len(seen) > 100
    for rec in seen:
        assert rec.linear_mps == pytest.approx(sv * raw[rec.stamp_ns].linear_mps, abs=1e-12)
        assert rec.angular_radps == pytest.approx(raw[rec.stamp_ns].angular_radps * np.array([1, 1, sw]), abs=1e-12)


def test_an_imu_mounting_the_calibration_could_not_measure_is_named(tmp_path):
    """No /tf_static: the IMU's yaw comes from --calib, where lio calibrate could only guess it on a ground robot."""
    sim = simulate("planar", tmp_path / "rover.mcap", "mcap", duration_s=4.0, seed=3, columns=360, tf_static=False)
    truth = Calibration.model_validate({"T_base_imu": _truth_T(sim), "T_base_imu_rotation_sigma_rad": [1e-4, 1e-4, 0.2]})
    res = run_odom(OdomJob(sim.log_path, config=OdomConfig(calibration=truth)))
    assert any(n.startswith("T_base_imu of --calib was not measured about the base z (1-sigma 11.5 deg)") for n in res.notes)


def _truth_T(sim) -> list:
    return json.loads(Path(sim.truth_path).read_text())["T_base_imu"]
