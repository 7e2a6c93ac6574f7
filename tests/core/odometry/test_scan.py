"""What every scan step shares: points in range, the degeneracy schedule, the pose recorded."""

import numpy as np

from lio_cli.config.odom import RegistrationConfig
from lio_cli.core.odometry.scan import finish, points_in_range, prepare
from lio_cli.core.odometry.state import WindowScan
from lio_cli.core.odometry.tuning import WHEEL_KEEP_NS
from lio_cli.model.records import OdometryRecord, PointCloud, TimeConvention

NS = 10**9


def _cloud(points) -> PointCloud:
    points = np.asarray(points, dtype=np.float64)
    stamps = np.linspace(0, NS // 10, len(points)).astype(np.int64)
    return PointCloud(0, "lidar", points, stamps, TimeConvention("stamps", "t", 1.0))


def test_points_are_moved_into_the_base_frame_and_kept_within_the_range_limits():
    T_base_lidar = np.eye(4)
    T_base_lidar[:3, 3] = [0.0, 0.0, 1.0]
    rc = RegistrationConfig(min_range_m=1.0, max_range_m=10.0)
    points, rng, keep = points_in_range(_cloud([[0.0, 0.0, -0.5], [3.0, 4.0, -1.0], [20.0, 0.0, 0.0]]), None, None,
                                        NS // 10, T_base_lidar, rc)
    np.testing.assert_allclose(points, [[0.0, 0.0, 0.5], [3.0, 4.0, 0.0], [20.0, 0.0, 1.0]])
    np.testing.assert_allclose(rng, [0.5, 5.0, np.hypot(20.0, 1.0)])
    assert keep.tolist() == [False, True, False]


def test_prepare_keeps_the_points_in_range_in_their_order(make_state):
    o = make_state()
    rng = np.random.default_rng(0)
    points = rng.uniform(-150.0, 150.0, (400, 3))  # the default limits keep 0.5-100 m
    kept = prepare(o, _cloud(points), None, None, NS // 10)
    base, ranges, keep = points_in_range(_cloud(points), None, None, NS // 10, o.ext.T_base_lidar, o.cfg.registration)
    assert 50 < keep.sum() < 400  # some dropped: the copying path
    np.testing.assert_array_equal(kept, base[keep])
    assert ((row := np.linalg.norm(kept, axis=1)) <= 100.0).all() and (row >= 0.5).all()


def test_too_few_points_in_range_skip_the_scan_and_start_no_map(make_state):
    o = make_state()
    assert prepare(o, _cloud(np.full((10, 3), 5.0)), None, None, NS // 10) is None
    assert o.stats.skipped_few_points == 1 and o.reg is None


def test_a_scan_is_recorded_on_the_track_and_old_wheel_records_dropped(make_state):
    o = make_state()
    o.wheel = [OdometryRecord(t, "odom", "base", None, np.zeros(3), np.zeros(3)) for t in (0, 2 * NS, 3 * NS)]
    res = finish(o, 3 * NS, np.eye(4), None, None, [np.array([1.0, 0.0, 0.0])], False)
    assert res.degenerate and not res.failed and res.stamp_ns == 3 * NS
    assert list(o.track.stamps_ns) == [3 * NS] and o.stats.used == 1 and o.stats.degenerate == 1
    assert [w.stamp_ns for w in o.wheel] == [3 * NS]  # older than WHEEL_KEEP_NS behind the scan: dropped
    o.startup.scans = [WindowScan(NS, 2 * NS, np.eye(4), np.nan, None, 0)]  # a start-up window holds them
    o.wheel.insert(0, OdometryRecord(NS - WHEEL_KEEP_NS // 2, "odom", "base", None, np.zeros(3), np.zeros(3)))
    finish(o, 4 * NS, np.eye(4), None, None, [], False)
    assert len(o.wheel) == 2


def test_the_analysis_schedule_repeats_lio_odoms_and_reanalyses_a_retried_scan(monkeypatch):
    """lio odom analyses a clear scene every 4th scan (degeneracy_every_clear), and a scan registered again (a
    failed registration retried LiDAR-only, or a doubted one) again; deskew's clear-scene schedule (8) skips
    the scans between too, but not a retried scan (its reuse would turn the
    directions by the motion between scans)."""
    import lio_cli.core.odometry.scan as scan
    from lio_cli.config.deskew import DeskewConfig
    from lio_cli.config.odom import OdomConfig
    from lio_cli.core.odometry.degeneracy import CLEAR_MARGIN, Degeneracy
    from lio_cli.core.odometry.state import DegeneracySchedule

    analysed = []

    def fake(points, planar, ratio):
        analysed.append(int(points[0, 0]))
        return Degeneracy([np.array([1.0, 0.0, 0.0])], 10 * CLEAR_MARGIN)  # clear by far

    monkeypatch.setattr(scan, "analyse_degeneracy", fake)
    for cfg, expected in ((OdomConfig(), [0, 0, 4, 8]),
                          (DeskewConfig().odom_config("imu"), [0, 0, 8])):
        analysed.clear()
        schedule = DegeneracySchedule()
        for used in (0, 0, 1, 2, 3, 4, 5, 6, 7, 8, 9, 10):  # scan 0 registered twice (a retry)
            dirs = scan.scheduled_directions(schedule, np.full((5, 3), float(used)), np.eye(3), np.eye(4), used,
                                             False, False, cfg.fusion)
            assert len(dirs) == 1
        assert analysed == expected, (cfg.fusion.degeneracy_every_clear, analysed)


def test_the_scan_sink_gets_each_placed_scans_points_and_a_replay_tells_it_again(make_scan, still_imu):
    from lio_cli.config.odom import OdomConfig
    from lio_cli.core.odometry import LioOdometry

    told: list[tuple[int, np.ndarray | None]] = []
    odo = LioOdometry(OdomConfig(), np.eye(4), use_imu=True, planar=False,
                      scan_sink=lambda stamp, pts: told.append((stamp, pts)))
    odo.set_imu_extrinsic(np.eye(4))
    odo.add_imu(still_imu(0, 3 * NS))
    for k in range(1, 21):
        odo.process(make_scan(np.eye(4), k * NS // 10))
    assert odo.imu_mode  # the start-up window was aligned with the IMU and replayed
    stamps = [s for s, _ in told]
    assert sorted(set(stamps)) == list(odo.stamps_ns) == [k * NS // 10 for k in range(1, 21)]
    assert len(stamps) > len(set(stamps))  # the window's scans were told again when replayed
    last = dict(told)
    cloud = make_scan(np.eye(4), NS // 10)
    for stamp, pts in last.items():
        assert pts is not None and len(pts) == len(cloud.points)  # standing still: every point, where it was
        np.testing.assert_allclose(pts, cloud.points, atol=1e-4)  # de-skewed by an IMU state at rest to 0.1 mm


def test_a_failed_scan_is_told_with_no_points(make_state):
    o = make_state()
    told = []
    o.scan_sink = lambda stamp, pts: told.append((stamp, pts))
    finish(o, NS, np.eye(4), None, None, [], True, np.zeros((5, 3)))
    assert told == [(NS, None)]
