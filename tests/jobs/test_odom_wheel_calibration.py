"""`lio odom --calib` applies the calibration's wheel scales to the wheel odometry it joins to the prediction."""

from __future__ import annotations

import numpy as np
import pytest

from lio_cli.config.odom import OdomConfig
from lio_cli.core.odometry import LioOdometry
from lio_cli.io.reader import open_log
from lio_cli.io.stream import SensorStream
from lio_cli.jobs.odom import OdomJob, run_odom
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
