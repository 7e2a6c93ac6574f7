"""A LiDAR gap bridged by the IMU state, on a constructed room with an IMU at rest."""

import numpy as np

from lio_cli.core.odometry.bridge import bridge
from lio_cli.core.odometry.lidar_step import lidar_step

NS = 10**9
POSITION_TOL_M = 0.02


def test_a_state_at_rest_is_carried_across_a_gap_and_the_scan_after_it_registered(make_state, make_scan, still_imu,
                                                                                  still_state):
    o = make_state(use_imu=True)
    lidar_step(o, make_scan(np.eye(4), NS), NS - NS // 10, NS)
    o.startup.scans = []
    o.imu_mounted = True
    o.imu.add(still_imu(0, 4 * NS))
    o.nav.state = still_state(NS)
    res = bridge(o, make_scan(np.eye(4), 3 * NS), NS, 3 * NS)
    assert not res.failed and np.linalg.norm(res.pose[:3, 3]) < POSITION_TOL_M
    assert o.nav.state.stamp_ns == 3 * NS
    [event] = o.events
    assert event["kind"] == "time gap" and event["reason"].startswith("2 s without a scan: bridged by the IMU state")
    assert "the scan after it registered 0.00 m from the prediction" in event["reason"]


def test_a_skipped_scan_after_a_gap_leaves_the_state_before_it(make_state, make_scan, still_imu, still_state):
    o = make_state(use_imu=True)
    lidar_step(o, make_scan(np.eye(4), NS), NS - NS // 10, NS)
    o.imu_mounted = True
    o.imu.add(still_imu(0, 4 * NS))
    o.nav.state = before = still_state(NS)
    empty = make_scan(np.eye(4), 3 * NS, points_world=np.full((100, 3), 0.1))
    assert bridge(o, empty, NS, 3 * NS) is None
    assert o.nav.state is before and o.events[0]["reason"].endswith("; the scan after it was skipped")
