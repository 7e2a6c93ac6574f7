"""IMU-primed scans the IMU state cannot explain: retried or placed LiDAR-only, on a constructed room."""

import numpy as np

from lio_cli.core.odometry.lidar_step import lidar_step
from lio_cli.core.odometry.recovery import doubted_scan, failed_registration
from lio_cli.geometry import make_pose

NS = 10**9
T1 = NS + NS // 10  # the scan after the mapped one
POSITION_TOL_M = 0.02
FAR = np.array([0.0, 0.0, 40.0])  # the room moved this far: in range, and no point near the map
OFF = make_pose(np.eye(3), [0.6, 0.0, 0.0])  # a registration the prediction (rest) cannot explain


def _mapped(make_state, make_scan, still_imu, still_state):
    o = make_state(use_imu=True)
    lidar_step(o, make_scan(np.eye(4), NS), NS - NS // 10, NS)
    o.imu_mounted = True
    o.imu.add(still_imu(0, 3 * NS))
    o.nav.state, o.nav.g_world = still_state(T1), np.array([0.0, 0.0, -9.81])
    return o


def test_a_failed_registration_the_lidar_alone_explains_drops_the_state(make_state, make_scan, still_imu,
                                                                       still_state):
    o = _mapped(make_state, make_scan, still_imu, still_state)
    res = failed_registration(o, make_scan(np.eye(4), T1), NS, T1, OFF, np.eye(4), [])
    assert not res.failed and np.linalg.norm(res.pose[:3, 3]) < POSITION_TOL_M
    assert o.nav.state is None and o.stats.recoveries == 1 and o.stats.registration_failures == 1
    assert o.events[-1]["kind"] == "recovery" and "0.60 m from it" in o.events[-1]["reason"]
    assert [w.stamp_ns for w in o.startup.scans] == [T1]  # the first scan of the window that restarts it


def test_a_scan_neither_explains_keeps_the_state_and_its_prediction(make_state, make_scan, room, still_imu,
                                                                    still_state):
    o = _mapped(make_state, make_scan, still_imu, still_state)
    kept = o.nav.state
    res = failed_registration(o, make_scan(np.eye(4), T1, points_world=room + FAR), NS, T1, OFF, np.eye(4), [])
    assert res.failed and o.nav.state is kept and o.health.lost == 1
    np.testing.assert_array_equal(res.pose, kept.pose())
    assert o.stats.recoveries == 0 and o.reg.scans == 1  # a failed scan stays out of the map


def test_a_doubted_scan_is_placed_lidar_only_and_the_state_follows_it(make_state, make_scan, still_imu,
                                                                     still_state):
    o = _mapped(make_state, make_scan, still_imu, still_state)
    kept = o.nav.state
    kept.v = np.array([0.3, 0.0, 0.0])
    o.health.doubt = 1
    truth = make_pose(np.eye(3), [0.05, 0.0, 0.0])
    res = doubted_scan(o, make_scan(truth, T1), NS, T1, OFF, np.eye(4), np.zeros((10, 3)), [], None)
    assert np.linalg.norm(res.pose[:3, 3] - truth[:3, 3]) < POSITION_TOL_M
    assert o.nav.state is kept and o.health.doubt == 1 and o.stats.doubted_scans == 1
    np.testing.assert_array_equal(kept.p, res.pose[:3, 3])  # the state follows the LiDAR-only pose...
    np.testing.assert_array_equal(kept.v, [0.3, 0.0, 0.0])  # ...and keeps its velocity
    assert o.startup.scans == [] and o.events == []


def test_doubted_scans_in_a_row_drop_the_state(make_state, make_scan, still_imu, still_state):
    o = _mapped(make_state, make_scan, still_imu, still_state)
    doubted_scan(o, make_scan(np.eye(4), T1), NS, T1, OFF, np.eye(4), np.zeros((10, 3)), [], "disagreed")
    assert o.nav.state is None and o.stats.recoveries == 1
    assert o.events[-1]["reason"] == "disagreed: back to LiDAR-only scans"
