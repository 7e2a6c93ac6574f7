"""Corrections of the IMU state by the registered pose, the wheel speed, and the clock tracker."""

import numpy as np

from lio_cli.config.odom import FusionConfig
from lio_cli.core.imu import NavState
from lio_cli.core.odometry.state import OdomStats
from lio_cli.core.odometry.updates import correct, track_clock, wheel_update
from lio_cli.geometry import make_pose, so3_exp
from lio_cli.model.records import OdometryRecord

NS = 10**9
EXACT = 1e-12


def _state(v=(0.0, 0.0, 0.0)) -> NavState:
    return NavState(0, np.eye(3), np.zeros(3), np.array(v, float), np.zeros(3), np.zeros(3))


def _wheel(stamps_ns, speed_mps, yaw_rate=0.0):
    return [OdometryRecord(t, "odom", "base", None, np.array([speed_mps, 0.0, 0.0]), np.array([0.0, 0.0, yaw_rate]))
            for t in stamps_ns]


def test_a_complementary_filter_of_alpha_one_takes_the_registered_pose():
    measured = make_pose(so3_exp(np.array([0.0, 0.0, 0.05])), [0.1, 0.2, 0.0])
    s = _state()
    pose = correct(s, measured, [], 0.1, FusionConfig(method="complementary", alpha=1.0), np.eye(3), planar=False)
    np.testing.assert_allclose(pose, measured, atol=EXACT)
    np.testing.assert_allclose(s.v, [1.0, 2.0, 0.0], atol=1e-9)  # the correction spread over the scan interval


def test_a_degenerate_direction_keeps_the_prediction_along_it():
    measured = make_pose(np.eye(3), [0.1, 0.2, 0.0])
    pose = correct(_state(), measured, [np.array([1.0, 0.0, 0.0])], 0.1, FusionConfig(method="complementary",
                   alpha=1.0), np.eye(3), planar=False)
    np.testing.assert_allclose(pose[:3, 3], [0.0, 0.2, 0.0], atol=EXACT)


def test_an_ekf_correction_moves_the_state_toward_the_registration_by_the_covariances():
    s = _state()
    s.P[3:6, 3:6] = np.eye(3) * 0.03**2  # as uncertain as the registration (position_sigma_m 0.03)
    pose = correct(s, make_pose(np.eye(3), [0.1, 0.0, 0.0]), [], 0.1, FusionConfig(), np.eye(3), planar=True)
    np.testing.assert_allclose(pose[0, 3], 0.05, rtol=1e-3)  # halfway
    assert pose[2, 3] == 0.0


def test_the_wheel_speed_corrects_the_velocity_unless_it_reads_zero_while_moving():
    stats = OdomStats()
    s = _state(v=(1.0, 0.0, 0.0))
    wheel_update(s, _wheel([NS, NS + NS // 20], 2.0), NS, NS + NS // 10, FusionConfig(method="complementary",
                 wheel_beta=0.5), stats)
    np.testing.assert_allclose(s.v, [1.5, 0.0, 0.0], atol=EXACT)
    assert stats.wheel_updates == 1
    wheel_update(s, _wheel([NS], 0.0), NS, NS + NS // 10, FusionConfig(), stats)
    assert stats.wheel_zero_skipped == 1 and s.v[0] == 1.5
    wheel_update(s, _wheel([5 * NS], 2.0), NS, NS + NS // 10, FusionConfig(), stats)  # none in the interval
    assert stats.wheel_updates == 1


class _Clock:
    """A clock tracker that proposes a fixed shift once it holds two poses."""

    done = False

    def __init__(self):
        self.poses = []

    def add_pose(self, stamp_ns, T_world_lidar, doubted):
        self.poses.append((stamp_ns, T_world_lidar[0, 3], doubted))

    def propose(self, gyro_bias, at_scan):
        return 2_000_000 if len(self.poses) == 2 else 0


def test_an_offset_the_clock_tracker_proposes_moves_every_imu_sample(make_state, still_state, still_imu):
    o = make_state(use_imu=True)
    o.nav.state = still_state(NS)
    o.imu.add(still_imu(0, NS))
    o.ext.T_base_lidar[0, 3] = 0.5  # the tracker gets T_world_lidar
    track_clock(o, NS, np.eye(4))  # no tracker: nothing
    o.clock = _Clock()
    track_clock(o, NS, np.eye(4))
    assert o.imu.shift_ns == 0 and o.events == []
    track_clock(o, 2 * NS, np.eye(4), doubted=True)
    assert o.clock.poses == [(NS, 0.5, False), (2 * NS, 0.5, True)]
    assert o.imu.shift_ns == 2_000_000 and o.imu.batches[0].stamps_ns[0] == 2_000_000
    assert o.events[-1]["kind"] == "clock offset" and "moved by +2.00 ms" in o.events[-1]["reason"]
    o.clock.done = True
    track_clock(o, 3 * NS, np.eye(4))
    assert len(o.clock.poses) == 2
