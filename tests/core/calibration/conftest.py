"""Synthetic calibration inputs with known truth, shared by the estimator tests (built once per session)."""

from __future__ import annotations

import pytest

from lio_cli.simulation.calibration_inputs import CalibrationInputs, calibration_inputs
from lio_cli.simulation.sensors import WheelSpec

HANDHELD_OFFSET_S = -0.037  # t_lidar = t_imu_stamp + offset: the IMU clock runs 37 ms ahead


@pytest.fixture(scope="session")
def handheld() -> CalibrationInputs:
    """30 s of handheld motion, LiDAR-only-like trajectory noise (1.5 cm, 0.1 deg), IMU 37 ms behind."""
    return calibration_inputs("handheld", 30.0, seed=3, imu_time_offset_s=HANDHELD_OFFSET_S)


@pytest.fixture(scope="session")
def handheld_quiet() -> CalibrationInputs:
    """As ``handheld`` with a quieter trajectory (0.5 cm), for tight lever-arm checks."""
    return calibration_inputs("handheld", 30.0, seed=4, pos_noise_m=0.005)


@pytest.fixture(scope="session")
def planar() -> CalibrationInputs:
    """40 s of a differential-drive robot (turns about the vertical only) with wheel errors and a slip."""
    wheels = WheelSpec(radius_m=0.08, baseline_m=0.42, radius_scale_left=1.012, radius_scale_right=0.993,
                       baseline_scale=1.04, slip_start_s=20.0, slip_duration_s=3.0, slip_left=0.25, slip_right=0.10)
    return calibration_inputs("planar", 40.0, seed=5, wheel_spec=wheels)

