"""The odometry's state objects: the track's last motion, the IMU buffer, dropping the IMU state."""

import numpy as np

from lio_cli.core.odometry.clock_offset import ClockOffsetTracker
from lio_cli.core.odometry.state import ImuBuffer, Track, WindowScan
from lio_cli.core.odometry.tuning import MIN_VELOCITY_DT_S
from lio_cli.geometry import make_pose
from lio_cli.model.records import ImuBatch

NS = 10**9
EXACT = 1e-12


def _at(x_m: float) -> np.ndarray:
    return make_pose(np.eye(3), [x_m, 0.0, 0.0])


def test_the_track_keeps_the_last_motion_over_its_interval():
    track = Track()
    track.append(NS, _at(0.0))
    assert track.last_dt_s == 0.0  # a first pose has no motion
    track.append(NS + NS // 10, _at(0.1))
    np.testing.assert_allclose(track.last_delta[:3, 3], [0.1, 0.0, 0.0], atol=EXACT)
    assert track.last_dt_s == 0.1 and track.last_ns == NS + NS // 10
    assert list(track.stamps_ns) == [NS, NS + NS // 10] and len(track.poses) == 2


def test_two_scans_too_close_for_a_velocity_extend_the_interval_back():
    track = Track()
    track.append(NS, _at(0.0))
    track.append(NS + NS // 10, _at(0.1))
    close = int(MIN_VELOCITY_DT_S * NS) // 2
    track.append(NS + NS // 10 + close, _at(0.11))
    np.testing.assert_allclose(track.last_delta[:3, 3], [0.11, 0.0, 0.0], atol=EXACT)  # the two intervals in one
    np.testing.assert_allclose(track.last_dt_s, 0.1 + close * 1e-9, rtol=EXACT)
    first = Track()
    first.append(NS, _at(0.0))
    first.append(NS + close, _at(0.01))
    np.testing.assert_array_equal(first.last_delta, np.eye(4))  # nothing to extend: no motion
    assert first.last_dt_s == 0.0


def test_restarting_the_track_drops_the_poses_from_an_index():
    track = Track()
    for k in range(4):
        track.append(NS + k * NS // 10, _at(0.1 * k))
    track.restart_at(1, _at(5.0))
    assert list(track.stamps_ns) == [NS] and track.last_ns is None and track.last_dt_s == 0.0
    np.testing.assert_array_equal(track.last_pose, _at(5.0))


def _batch(t0_ns: int, n: int) -> ImuBatch:
    stamps = t0_ns + np.arange(n, dtype=np.int64) * 10_000_000
    return ImuBatch("imu", stamps, np.zeros((n, 3)), np.zeros((n, 3)))


def test_the_imu_buffer_moves_samples_buffered_and_to_come_by_the_clock_shift():
    buf = ImuBuffer()
    buf.add(_batch(0, 5))
    buf.shift(3_000_000)
    stored = buf.add(_batch(50_000_000, 5))
    assert buf.batches[0].stamps_ns[0] == 3_000_000 and stored.stamps_ns[0] == 53_000_000
    assert buf.shift_ns == 3_000_000 and buf.until_ns() == 93_000_000


def test_the_imu_window_drops_samples_older_than_two_before_its_start_unless_held():
    buf = ImuBuffer()
    buf.add(_batch(0, 10))
    held = buf.window(50_000_000, hold_ns=20_000_000)
    assert held.stamps_ns[0] == 0  # two samples before the held start
    imu = buf.window(50_000_000)
    assert imu.stamps_ns[0] == 30_000_000 and len(buf.batches) == 1 and len(buf.batches[0]) == 7


def test_losing_the_imu_state_ends_the_start_up_window_doubt_and_imu_gap(make_state, still_state):
    o = make_state(use_imu=True)
    o.nav.state, o.nav.g_world = still_state(NS), np.array([0.0, 0.0, -9.81])
    o.clock = ClockOffsetTracker()
    o.clock.add_pose(NS, np.eye(4))
    o.startup.scans = [WindowScan(0, NS, np.eye(4), np.nan, None, 0)]
    o.health.doubt, o.gaps.imu_gap_from = 2, (np.eye(4), NS, {})
    o.lose_imu_state(keep_clock=True)
    assert o.nav.state is None and o.startup.scans == [] and o.health.doubt == 0 and o.gaps.imu_gap_from is None
    assert o.nav.g_world is not None and o.clock._stamps == [NS]  # gravity and (here) the clock's window kept
    o.lose_imu_state()
    assert o.clock._stamps == []


def test_an_event_names_the_scan_and_the_stamp_before_it(make_state):
    o = make_state()
    o.stats.scans, o.track.last_ns = 7, 3 * NS
    event = o.event("time gap", "why")
    assert o.events == [{"kind": "time gap", "scan": 7, "after_stamp_ns": 3 * NS, "reason": "why"}]
    assert event is o.events[0]


def test_registration_times_give_their_median_and_90th_percentile_in_ms():
    from lio_cli.core.odometry.state import OdomStats
    stats = OdomStats()
    assert stats.register_ms() == {"register_median": None, "register_p90": None}
    for s in (0.004, 0.002, 0.003, 0.010, 0.001):
        stats.registered(s)
    assert stats.register_ms() == {"register_median": 3.0, "register_p90": 7.6}
    assert abs(stats.times_s["register"] - 0.020) < EXACT
    assert "register_s" not in stats.counts()  # the counters only
