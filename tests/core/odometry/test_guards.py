"""Guards of the scan steps, on constructed poses and states."""

import numpy as np
import pytest

from lio_cli.config.odom import FusionConfig, RegistrationConfig
from lio_cli.core.imu import NavState
from lio_cli.core.odometry.clock_offset import ClockOffsetTracker
from lio_cli.core.odometry.guards import (count_lost, icp_cap, implausible, predicted_only, registration_failed,
                                          state_implausible, turning_slowly)
from lio_cli.core.odometry.state import Diverged, Health, OdomStats, Track
from lio_cli.core.odometry.tuning import MAX_JUMP_M, MAX_JUMP_RAD, NIS_SCANS, PREDICT_MIN_MAP_SCANS
from lio_cli.geometry import make_pose, so3_exp
from lio_cli.model.records import ImuBatch

NS = 10**9


def _moved(dx_m: float = 0.0, yaw_rad: float = 0.0) -> np.ndarray:
    return make_pose(so3_exp(np.array([0.0, 0.0, yaw_rad])), [dx_m, 0.0, 0.0])


def _state(v=(0.0, 0.0, 0.0), bg=(0.0, 0.0, 0.0), ba=(0.0, 0.0, 0.0)) -> NavState:
    return NavState(0, np.eye(3), np.zeros(3), np.array(v, float), np.array(bg, float), np.array(ba, float))


@pytest.mark.parametrize("measured, gate_m, failed", [
    (_moved(0.1), None, False),
    (_moved(MAX_JUMP_M * 1.1), None, True),  # further than a scan can move from the prediction
    (_moved(yaw_rad=MAX_JUMP_RAD * 1.1), None, True),
    (_moved(MAX_JUMP_M * 1.1), MAX_JUMP_M * 1.5, False),  # a bridged gap's wider gate
    (np.eye(4), None, True),  # the guess itself: nothing matched
    (np.full((4, 4), np.nan), None, True),
])
def test_a_registration_fails_when_the_prediction_cannot_explain_it(measured, gate_m, failed):
    guess = np.eye(4)
    assert registration_failed(measured, guess, map_empty=False, gate_m=gate_m) is failed


def test_on_an_empty_map_only_a_non_finite_registration_fails():
    assert not registration_failed(np.eye(4), np.eye(4), map_empty=True)
    assert registration_failed(np.full((4, 4), np.inf), np.eye(4), map_empty=True)


def test_innovations_far_outside_the_covariance_doubt_then_drop_the_state():
    fc = FusionConfig()
    far = _moved(1.0)  # 1 m off a state sure to a millimetre: NIS in the hundreds of thousands
    doubt, reason = 0, None
    for k in range(1, NIS_SCANS + 1):
        doubt, reason = implausible(_state(), far, [], fc, doubt)
        assert doubt == k
    assert reason.startswith(f"prediction and registration disagreed for {NIS_SCANS} scans")
    assert implausible(_state(), _moved(1e-4), [], fc, doubt) == (0, None)  # an innovation that fits ends it
    assert implausible(_state(), far, [], FusionConfig(method="complementary"), 2) == (2, None)  # EKF only


@pytest.mark.parametrize("state, words", [
    (_state(), None),
    (_state(v=(80.0, 0.0, 0.0)), "speed 80.0 m/s beyond max_speed_mps"),
    (_state(v=(np.nan, 0.0, 0.0)), "the IMU state became non-finite"),
    (_state(bg=(0.6, 0.0, 0.0)), "IMU biases implausible (gyro 0.60 rad/s, accel 0.00 m/s^2)"),
    (_state(ba=(0.0, 3.5, 0.0)), "IMU biases implausible (gyro 0.00 rad/s, accel 3.50 m/s^2)"),
])
def test_an_implausible_state_is_named(state, words):
    assert state_implausible(state, max_speed_mps=70.0) == words


def test_the_run_ends_after_max_lost_scans_in_a_row():
    health = Health(lost=1)
    count_lost(health, 3, scan=10, t_ref=12 * NS)
    assert health.lost == 2
    with pytest.raises(Diverged, match=r"lost track at scan 11 \(stamp 13.000 s\).* 3 scans in a row"):
        count_lost(health, 3, scan=11, t_ref=13 * NS)


def test_turning_slowly_looks_at_the_gyro_over_the_scan_interval_only():
    stamps = np.arange(0, NS + 1, 10_000_000, dtype=np.int64)
    gyro = np.zeros((len(stamps), 3))
    gyro[stamps > 600_000_000, 2] = np.radians(20.0)  # turning fast after 0.6 s
    imu = ImuBatch("imu", stamps, gyro, np.zeros_like(gyro))
    rc = RegistrationConfig(slow_register_every=2, slow_rate_degps=5.0)
    assert turning_slowly(imu, 100_000_000, 500_000_000, np.zeros(3), rc)
    assert not turning_slowly(imu, 500_000_000, 800_000_000, np.zeros(3), rc)
    assert turning_slowly(imu, 500_000_000, 800_000_000, np.array([0.0, 0.0, np.radians(20.0)]), rc) is False
    assert not turning_slowly(imu, 100_000_000, 500_000_000, np.zeros(3), RegistrationConfig())  # lio odom: not asked


def test_the_icp_cap_leans_on_the_prediction_only_where_it_may():
    rc = RegistrationConfig(steady_iterations=5, slow_iterations=3)
    clock = ClockOffsetTracker()
    assert icp_cap(True, rc, clock) == 3
    assert icp_cap(False, rc, clock) is None  # the clock still needs converged poses
    assert icp_cap(False, rc, None) == 5
    assert icp_cap(True, RegistrationConfig(), None) is None


def test_of_slowly_turning_scans_every_nth_is_registered():
    track, stats = Track(), OdomStats()
    taken = [predicted_only(True, 3, track, 0, True, PREDICT_MIN_MAP_SCANS, stats) for _ in range(7)]
    assert taken == [True, True, False, True, True, False, True] and stats.predicted_scans == 5
    assert not predicted_only(True, 3, Track(), 1, True, PREDICT_MIN_MAP_SCANS, stats)  # in doubt
    assert not predicted_only(True, 3, Track(), 0, False, PREDICT_MIN_MAP_SCANS, stats)  # a scene near degeneracy
    assert not predicted_only(True, 3, Track(), 0, True, PREDICT_MIN_MAP_SCANS - 1, stats)  # a young map
    assert not predicted_only(False, 3, Track(), 0, True, PREDICT_MIN_MAP_SCANS, stats)
