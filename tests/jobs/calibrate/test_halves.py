"""The gyro's mounting from each half of the trajectory: their disagreement joins the rotation's 1-sigma."""

from __future__ import annotations

import numpy as np
import pytest

from lio_cli.core.calibration import estimate_rotation
from lio_cli.core.calibration.time_offset import TimeOffset
from lio_cli.geometry import so3_exp
from lio_cli.jobs.calibrate.estimate import Estimates
from lio_cli.jobs.calibrate.halves import halves_spread
from lio_cli.jobs.calibrate.passes import LidarTrajectory
from lio_cli.model.records import ImuBatch
from lio_cli.simulation.calibration_inputs import calibration_inputs


@pytest.fixture(scope="module")
def walk():
    return calibration_inputs("handheld", 30.0, 3)


def run(ci, tilt_deg: float) -> tuple[np.ndarray, np.ndarray, Estimates]:
    """(1-sigma before, after, the estimates) with the second half's LiDAR turned ``tilt_deg`` about its x axis
    (as if the IMU had moved on its mount half-way)."""
    P = ci.T_world_lidar.copy()
    n = len(P)
    P[n // 2:, :3, :3] = P[n // 2:, :3, :3] @ so3_exp(np.radians([tilt_deg, 0.0, 0.0]))
    imu = ImuBatch("imu", ci.imu.stamps_ns, ci.imu.gyro_radps, ci.imu.accel_mps2)
    rot = estimate_rotation(ci.lidar_stamps_ns, P, imu.stamps_ns, imu.gyro_radps)
    est = Estimates(rotation=rot, offset=TimeOffset(0.0, 1e-5, 1.0, np.eye(3), np.zeros(3), n, 0.0, ()))
    halves_spread(LidarTrajectory(ci.lidar_stamps_ns, P, n, n, "test"), imu, est)
    return np.degrees(rot.sigma_rad), np.degrees(est.rotation.sigma_rad), est


def test_a_mounting_that_moved_half_way_is_reported_with_the_difference_in_its_sigma(walk):
    before, after, est = run(walk, 0.4)
    print(f"1-sigma {before.round(3)} -> {after.round(3)} deg")
    assert before[0] < 0.1 and after[0] >= 0.17  # about half the 0.4 deg the halves disagree by
    assert (after[1:] < 2 * before[1:] + 0.02).all()
    assert (est.rotation.observable == (before <= 1.0)).all() and not est.skipped  # all still within 1 deg


def test_an_axis_the_halves_disagree_on_by_degrees_is_no_longer_estimated(walk):
    before, after, est = run(walk, 3.0)
    assert before[0] < 1.0 < after[0] and not est.rotation.observable[0]
    assert [s.key for s in est.skipped] == ["rotation_x"]
    assert est.skipped[0].line().startswith("not estimated: the mounting's rotation about the LiDAR x axis: the two "
                                            "halves of the log put it 2.")


def test_a_consistent_trajectory_keeps_its_sigma_nearly(walk):
    before, after, _ = run(walk, 0.0)
    print(f"1-sigma {before.round(3)} -> {after.round(3)} deg")
    assert (after >= before).all() and (after < 2 * before + 0.02).all()
