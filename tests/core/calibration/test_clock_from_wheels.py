"""The IMU's clock offset from a ground robot's wheels: their turn rate against the gyro's."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from lio_cli.core.calibration.clock_from_wheels import estimate_clock_from_wheels, with_wheel_clock
from lio_cli.core.calibration.time_offset import TimeOffset
from lio_cli.errors import InputError
from lio_cli.geometry import so3_exp
from lio_cli.simulation.calibration_inputs import calibration_inputs
from lio_cli.simulation.scenarios import build_scenario


def rover(offset_s: float, seed: int, slip: bool = False, rotation_deg=(180.0, 0.0, 90.0)):
    """A 20 s planar robot, its IMU mounted ``rotation_deg`` and stamped ``offset_s`` off, its wheels 1.2 / 0.7 %
    off in radius (and slipping for 1 s at 8 s)."""
    T = np.eye(4)
    T[:3, :3] = so3_exp(np.radians(rotation_deg))
    spec = replace(build_scenario("planar").wheels, radius_scale_left=1.012, radius_scale_right=0.993,
                   bursts=((8.0, 1.0, 0.08, 0.0),) if slip else ())
    return calibration_inputs("planar", 20.0, seed, imu_time_offset_s=offset_s, T_base_imu=T, wheel_spec=spec)


@pytest.mark.parametrize("offset_s,seed,slip", [(-0.040, 0, False), (0.015, 1, True), (0.0, 2, True)])
def test_the_wheels_time_the_imu_within_a_millisecond(offset_s, seed, slip):
    ci = rover(offset_s, seed, slip)
    w = ci.wheel
    r = estimate_clock_from_wheels(w.stamps_ns, w.angular_radps, ci.imu.stamps_ns, ci.imu.gyro_radps,
                                   speed_mps=w.linear_mps)
    err_ms = 1e3 * (r.imu_time_offset_s - offset_s)
    print(f"offset {1e3 * offset_s:+.0f} ms: {err_ms:+.3f} ms, 1-sigma {1e3 * r.sigma_s:.3f} ms, {r.notes}")
    assert abs(err_ms) < 1.0
    assert abs(err_ms) <= 3 * 1e3 * r.sigma_s and r.sigma_s < 0.001
    assert abs(r.explained - 1.0) < 0.01
    # the base's vertical in the IMU frame: the third row of R_base_imu
    assert abs(r.axis_imu @ ci.T_base_imu[2, :3]) > 0.999
    assert bool(r.notes) == slip  # the slipping second is left out, and said so


def test_a_robot_that_does_not_turn_cannot_time_its_imu():
    ci = rover(0.0, 0)
    w = ci.wheel
    with pytest.raises(InputError, match=r"^clock offset from the wheels: the wheels' turn rate hardly changes"):
        estimate_clock_from_wheels(w.stamps_ns, 0.0 * w.angular_radps, ci.imu.stamps_ns, ci.imu.gyro_radps)


def test_another_vehicles_wheels_do_not_time_the_imu():
    ci = rover(0.0, 0)
    w = ci.wheel
    gyro = np.random.default_rng(5).normal(0.0, 0.2, ci.imu.gyro_radps.shape)  # turns of something else
    with pytest.raises(InputError, match=r"^clock offset from the wheels: (the gyro explains \d+% of the wheels' turn rate"
                                         r"|the best offset lies at the edge|too little change)"):
        estimate_clock_from_wheels(w.stamps_ns, w.angular_radps, ci.imu.stamps_ns, gyro)


def _offset(value_s: float, sigma_s: float, note: str = "x") -> TimeOffset:
    return TimeOffset(value_s, sigma_s, 0.9, np.eye(3), np.zeros(3), 100, 0.001, (note,))


def test_the_wheels_offset_is_used_where_the_lidar_could_not_time_the_imu_and_combined_where_both_agree():
    ci = rover(0.015, 1)
    w = ci.wheel
    wc = estimate_clock_from_wheels(w.stamps_ns, w.angular_radps, ci.imu.stamps_ns, ci.imu.gyro_radps,
                                    speed_mps=w.linear_mps)
    kept = with_wheel_clock(_offset(0.0, float("nan"), "too little rotation"), wc)
    assert kept.imu_time_offset_s == wc.imu_time_offset_s and kept.sigma_s == wc.sigma_s
    assert kept.notes[0].startswith("the clock offset from the wheels' turn rate against the gyro's: +15.")
    assert "the LiDAR's rotations could not time the IMU (too little rotation)" in kept.notes[0]
    both = with_wheel_clock(_offset(0.016, 0.002), wc)  # agrees: inverse-variance mean, sharper than either
    assert wc.imu_time_offset_s < both.imu_time_offset_s < 0.016 and both.sigma_s < wc.sigma_s
    apart = with_wheel_clock(_offset(0.030, 0.001), wc)  # 15 ms apart: the wheels keep another clock
    assert apart.imu_time_offset_s == 0.030 and apart.sigma_s == 0.001
    assert "the wheel odometry seems to keep another clock; not used" in apart.notes[-1]
