"""Gaps: the gate after a bridged LiDAR gap, why a gap is not bridged, the state re-seeded after an IMU gap."""

import numpy as np
import pytest

from lio_cli.core.imu import NavState
from lio_cli.core.odometry.gaps import bridge_gate_m, bridge_refused, reseeded
from lio_cli.core.odometry.tuning import GATE_M, MAX_BRIDGE_GATE_M, RESEED_SIGMA_M
from lio_cli.geometry import make_pose
from lio_cli.model.records import ImuBatch

NS = 10**9


@pytest.mark.parametrize("gap_s, gate_m", [(0.0, GATE_M), (2.0, 0.5 + 3.0 * (0.05 * 2.0 + 0.05 * 4.0)),
                                           (30.0, MAX_BRIDGE_GATE_M)])
def test_the_gate_widens_by_three_drifts_up_to_the_adaptive_start(gap_s, gate_m):
    assert bridge_gate_m(gap_s) == pytest.approx(gate_m, abs=1e-12)


def _imu(stamps_s) -> ImuBatch:
    stamps = (np.asarray(stamps_s) * NS).astype(np.int64)
    return ImuBatch("imu", stamps, np.zeros((len(stamps), 3)), np.zeros((len(stamps), 3)))


def test_a_gap_is_bridged_only_with_a_state_an_imu_across_it_and_within_max_bridge_s():
    asked = []

    def window(t0):
        asked.append(t0)
        return _imu(np.arange(0.0, 4.0, 0.01))

    assert bridge_refused(False, window, NS, 3 * NS, 3.0) == "no IMU state to carry across it"
    assert bridge_refused(True, window, NS, 5 * NS, 3.0) == "longer than max_bridge_s, 3 s"
    assert asked == []  # the IMU is not windowed for a gap refused before it is looked at
    assert bridge_refused(True, window, NS, 3 * NS, 3.0) is None
    holed = lambda t0: _imu(np.r_[np.arange(0.0, 1.5, 0.01), np.arange(2.0, 4.0, 0.01)])  # noqa: E731
    assert bridge_refused(True, holed, NS, 3 * NS, 3.0) == "the IMU has a 0.51 s gap in it too"


def test_a_reseeded_state_keeps_biases_and_gravity_and_widens_pose_and_velocity():
    kept = NavState(0, np.eye(3), np.zeros(3), np.ones(3), np.full(3, 0.01), np.full(3, 0.02), np.eye(18) * 1e-4)
    pose = make_pose(np.eye(3), [1.0, 2.0, 0.0])
    s = reseeded(kept, 5 * NS, pose, np.array([0.5, 0.0, 0.0]))
    assert s.stamp_ns == 5 * NS and s is not kept
    np.testing.assert_array_equal(s.p, [1.0, 2.0, 0.0])
    np.testing.assert_array_equal(s.v, [0.5, 0.0, 0.0])
    np.testing.assert_array_equal(s.bg, kept.bg)
    np.testing.assert_array_equal(s.g, kept.g)
    assert s.P[4, 4] == RESEED_SIGMA_M**2 and s.P[0, 9] == 0.0 and s.P[12, 12] == 1e-4
    np.testing.assert_array_equal(reseeded(kept, 5 * NS, pose, None).v, np.ones(3))  # no velocity: kept
    np.testing.assert_array_equal(kept.p, np.zeros(3))  # the kept state is untouched
