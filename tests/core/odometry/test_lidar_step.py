"""The LiDAR-only step on scans of a constructed room from known poses."""

import numpy as np
import pytest

from lio_cli.core.odometry.lidar_step import imu_hole, lidar_step
from lio_cli.core.odometry.state import Diverged
from lio_cli.geometry import make_pose, so3_exp, so3_log

NS = 10**9
POSITION_TOL_M = 0.02  # registration of a dense, noise-free room scan
ROTATION_TOL_RAD = np.radians(0.2)
FAR = np.array([0.0, 0.0, 40.0])  # the room moved this far: in range, and no point near the map


def _errors(pose, truth):
    return np.linalg.norm(pose[:3, 3] - truth[:3, 3]), np.linalg.norm(so3_log(truth[:3, :3].T @ pose[:3, :3]))


def test_the_first_scan_starts_the_map_at_the_origin(make_state, make_scan):
    o = make_state(prior="none", deskew="none")
    res = lidar_step(o, make_scan(np.eye(4), NS), NS - NS // 10, NS)
    np.testing.assert_array_equal(res.pose, np.eye(4))
    assert not res.failed and o.reg is not None and o.reg.scans == 1
    assert list(o.track.stamps_ns) == [NS] and o.stats.used == 1 and o.stats.lidar_only_scans == 1
    assert o.startup.scans == [] and not o.startup.due  # no IMU: nothing to start


def test_a_moved_scan_is_registered_where_it_was_taken(make_state, make_scan):
    o = make_state(prior="none", deskew="none")
    lidar_step(o, make_scan(np.eye(4), NS), NS - NS // 10, NS)
    truth = make_pose(so3_exp(np.array([0.0, 0.0, np.radians(3.0)])), [0.3, -0.2, 0.05])
    res = lidar_step(o, make_scan(truth, 2 * NS // 10 + NS), NS, NS + 2 * NS // 10)
    dp, dr = _errors(res.pose, truth)
    assert dp < POSITION_TOL_M and dr < ROTATION_TOL_RAD, (dp, dr)
    assert not res.failed and o.health.lost == 0 and o.reg.scans == 2


def test_a_scan_that_matches_nothing_fails_a_retry_without_a_trace(make_state, make_scan, room):
    o = make_state(prior="none", deskew="none")
    lidar_step(o, make_scan(np.eye(4), NS), NS - NS // 10, NS)
    elsewhere = make_scan(np.eye(4), 2 * NS, points_world=room + FAR)  # no correspondence at all
    assert lidar_step(o, elsewhere, NS, 2 * NS, retry=True) is None
    assert o.stats.skipped_few_points == 0  # registered, and failed
    assert len(o.track.poses) == 1 and o.stats.registration_failures == 0 and o.health.lost == 0


def test_failed_scans_keep_the_prior_and_too_many_in_a_row_end_the_run(make_state, make_scan, room):
    o = make_state(prior="none", deskew="none", max_lost_scans=3)
    lidar_step(o, make_scan(np.eye(4), NS), NS - NS // 10, NS)
    o.reg.scans = 2  # a map of more than one scan is never restarted
    for k in (1, 2):
        res = lidar_step(o, make_scan(np.eye(4), (1 + k) * NS, points_world=room + FAR), k * NS, (1 + k) * NS)
        assert res.failed and o.health.lost == k
        np.testing.assert_array_equal(res.pose, np.eye(4))  # the prior: the last pose
    with pytest.raises(Diverged, match="3 scans in a row"):
        lidar_step(o, make_scan(np.eye(4), 4 * NS, points_world=room + FAR), 3 * NS, 4 * NS)


def test_a_one_scan_map_nothing_matches_is_restarted(make_state, make_scan, room):
    o = make_state(prior="none", deskew="none")
    lidar_step(o, make_scan(np.eye(4), NS), NS - NS // 10, NS)
    for k in (1, 2, 3):
        lidar_step(o, make_scan(np.eye(4), (1 + k) * NS, points_world=room + FAR), k * NS, (1 + k) * NS)
    assert o.reg is None and o.health.map_restarts == 1
    assert [e["kind"] for e in o.events] == ["map restarted"]


def test_a_scan_with_an_imu_joins_the_start_up_window(make_state, make_scan, still_imu):
    o = make_state(use_imu=True, deskew="none")
    o.imu_mounted = True
    o.imu.add(still_imu(0, 2 * NS))
    lidar_step(o, make_scan(np.eye(4), NS), NS - NS // 10, NS)
    assert [w.stamp_ns for w in o.startup.scans] == [NS] and o.startup.due
    np.testing.assert_allclose(o.startup.first_f_base, [0.0, 0.0, 9.81])  # "up" from the IMU at rest
    assert not lidar_step(o, make_scan(np.eye(4), 2 * NS), NS, 2 * NS, window=False).failed
    assert len(o.startup.scans) == 1


def test_an_imu_hole_in_the_scan_interval_is_found_and_counted(make_state, still_imu):
    o = make_state(use_imu=True)
    o.imu_mounted = True
    imu = still_imu(0, 2 * NS)
    keep = (imu.stamps_ns < 1_300_000_000) | (imu.stamps_ns > 1_400_000_000)  # 100 ms without a sample
    o.imu.add(type(imu)("imu", imu.stamps_ns[keep], imu.gyro_radps[keep], imu.accel_mps2[keep]))
    assert not imu_hole(o, NS, 1_200_000_000)
    assert imu_hole(o, 1_200_000_000, 1_500_000_000)
    assert o.stats.imu_gaps == 1
    assert not imu_hole(make_state(use_imu=True), NS, 2 * NS)  # no IMU mounted: nothing to prime with
