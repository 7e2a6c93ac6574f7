"""The IMU-primed step on a constructed room, an IMU at rest and a state at rest."""

import numpy as np

from lio_cli.core.odometry.imu_step import imu_step
from lio_cli.core.odometry.lidar_step import lidar_step
from lio_cli.geometry import make_pose, so3_exp, so3_log

NS = 10**9
T0 = NS  # the first scan's end
POSITION_TOL_M = 0.02
ROTATION_TOL_RAD = np.radians(0.2)
STILL_SPEED_TOL_MPS = 0.05  # a state at rest, corrected by scans at rest, stays about at rest


def _mapped(make_state, make_scan, still_imu, still_state, **config):
    """An odometry state whose map holds the room from the origin, with an IMU at rest and a state at rest."""
    o = make_state(use_imu=True, **config)
    lidar_step(o, make_scan(np.eye(4), T0), T0 - NS // 10, T0)
    o.startup.scans = []
    o.imu_mounted = True
    o.imu.add(still_imu(0, 3 * NS))
    o.nav.state = still_state(T0)
    o.nav.g_world = o.nav.state.g.copy()
    return o


def test_a_scan_at_rest_is_placed_at_rest_and_corrects_the_state(make_state, make_scan, still_imu, still_state):
    o = _mapped(make_state, make_scan, still_imu, still_state)
    used = o.stats.used
    for k in (1, 2, 3):
        res = imu_step(o, make_scan(np.eye(4), T0 + k * NS // 10), T0 + (k - 1) * NS // 10, T0 + k * NS // 10)
        assert not res.failed
        assert np.linalg.norm(res.pose[:3, 3]) < POSITION_TOL_M
        assert np.linalg.norm(so3_log(res.pose[:3, :3])) < ROTATION_TOL_RAD
    assert o.stats.used == used + 3 and o.health.lost == 0 and o.nav.state is not None
    assert o.nav.state.stamp_ns == T0 + 3 * NS // 10
    assert np.linalg.norm(o.nav.state.v) < STILL_SPEED_TOL_MPS
    assert o.events == []


def test_a_scan_off_the_prediction_is_placed_by_the_registration(make_state, make_scan, still_imu, still_state):
    """The state predicts rest; the scan was taken 0.15 m and 2 deg away (within the gate): the EKF pulls the pose
    toward the registration by its covariance."""
    o = _mapped(make_state, make_scan, still_imu, still_state)
    o.nav.state.P[3:6, 3:6] = np.eye(3) * 0.3**2  # an uncertain position: the scan decides
    o.nav.state.P[0:3, 0:3] = np.eye(3) * 0.1**2
    truth = make_pose(so3_exp(np.array([0.0, 0.0, np.radians(2.0)])), [0.15, 0.0, 0.0])
    res = imu_step(o, make_scan(truth, T0 + NS // 10), T0, T0 + NS // 10)
    assert not res.failed
    assert np.linalg.norm(res.pose[:3, 3] - truth[:3, 3]) < POSITION_TOL_M
    assert np.linalg.norm(so3_log(truth[:3, :3].T @ res.pose[:3, :3])) < ROTATION_TOL_RAD


def test_a_skipped_scan_leaves_the_state_where_it_was(make_state, make_scan, still_imu, still_state):
    o = _mapped(make_state, make_scan, still_imu, still_state)
    before, poses = o.nav.state, len(o.track.poses)
    empty = make_scan(np.eye(4), T0 + NS // 10, points_world=np.full((100, 3), 0.1))  # all within min_range_m
    assert imu_step(o, empty, T0, T0 + NS // 10) is None
    assert o.nav.state is before and len(o.track.poses) == poses and o.stats.skipped_few_points == 1


def test_a_scan_over_an_imu_gap_is_placed_lidar_only_and_reseeds_the_state(make_state, make_scan, still_imu,
                                                                            still_state):
    o = _mapped(make_state, make_scan, still_imu, still_state)
    imu = o.imu.batches[0]
    keep = (imu.stamps_ns <= T0 + 10_000_000) | (imu.stamps_ns >= T0 + 2 * NS // 10)  # 190 ms without a sample
    o.imu.batches = [type(imu)("imu", imu.stamps_ns[keep], imu.gyro_radps[keep], imu.accel_mps2[keep])]
    res = imu_step(o, make_scan(np.eye(4), T0 + NS // 10), T0, T0 + NS // 10)
    assert not res.failed and np.linalg.norm(res.pose[:3, 3]) < POSITION_TOL_M
    assert [e["kind"] for e in o.events] == ["imu gap"]
    assert o.nav.state is not None and o.nav.state.stamp_ns == T0 + NS // 10  # re-seeded at the scan
    assert o.reg.scans == 1  # kept out of the map


def test_a_state_gone_implausible_is_dropped_after_its_scan(make_state, make_scan, still_imu, still_state):
    o = _mapped(make_state, make_scan, still_imu, still_state, max_speed_mps=1.0)
    o.nav.state.v = np.array([5.0, 0.0, 0.0])  # beyond max_speed_mps; the scan says it stood still
    o.nav.state.P[6:9, 6:9] = np.eye(3) * 1e-6  # and the state is sure of it
    o.nav.state.P[3:6, 3:6] = np.eye(3) * 1.0  # but not of its position: the scan is believed
    res = imu_step(o, make_scan(np.eye(4), T0 + NS // 10), T0, T0 + NS // 10)
    assert res is not None and o.nav.state is None
    assert o.stats.recoveries == 1 and "beyond max_speed_mps" in o.events[-1]["reason"]
