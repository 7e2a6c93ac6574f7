"""The (re)start of the IMU state from the window of LiDAR-only scans, and the window's replay."""

import numpy as np

from lio_cli.core.odometry.bootstrap import Bootstrap
from lio_cli.core.odometry.startup import replay, start_state, try_start
from lio_cli.core.odometry.state import WindowScan
from lio_cli.geometry import make_pose
from lio_cli.model.calibration import Extrinsics

NS = 10**9
G = 9.81
EXACT = 1e-12


def _window(n: int, v_mps: float = 0.0, t0_ns: int = NS) -> list[WindowScan]:
    """``n`` scans 0.1 s apart moving along x at ``v_mps``."""
    return [WindowScan(t0_ns + (k - 1) * NS // 10, t0_ns + k * NS // 10,
                       make_pose(np.eye(3), [v_mps * 0.1 * k, 0.0, 0.0]), np.nan, None, k) for k in range(n)]


def test_a_standing_start_is_pinned_and_starts_at_the_first_scans_start(still_imu):
    boot = Bootstrap(True, 2 * NS, np.zeros(3), np.zeros(3), np.array([0.0, 0.0, -G]), np.zeros(3), 11, "still")
    first = _window(1)[0]
    s = start_state(boot, first, still_imu(0, 3 * NS), Extrinsics(np.eye(4), np.eye(4)), np.zeros(3), planar=False)
    assert s.stamp_ns == first.t_prev_ns
    np.testing.assert_allclose(s.R, np.eye(3), atol=EXACT)  # the gyro at rest: no rotation back over the sweep
    np.testing.assert_allclose(s.p, first.pose[:3, 3], atol=EXACT)
    assert s.P[2, 2] == 1e-2 and s.P[6, 6] == 1e-4  # yaw free, velocity pinned
    np.testing.assert_allclose(s.P[15:18, 15:18], np.diag([0.01**2 + 1e-8] * 2 + [1e-8]), atol=EXACT)  # tilt only


def test_a_moving_start_starts_back_over_the_first_sweep_at_its_velocity(still_imu):
    v = np.array([2.0, 0.0, 0.0])
    boot = Bootstrap(False, 2 * NS, v, v, np.array([0.0, 0.0, -G]), np.zeros(3), 11, "moving")
    first = WindowScan(NS - NS // 10, NS, make_pose(np.eye(3), [1.0, 0.0, 0.0]), np.nan, None, 0)
    s = start_state(boot, first, still_imu(0, 3 * NS), Extrinsics(np.eye(4), np.eye(4)), np.zeros(3), planar=True)
    np.testing.assert_allclose(s.p, [0.8, 0.0, 0.0], atol=EXACT)  # 0.1 s at 2 m/s before the first scan's end
    np.testing.assert_array_equal(s.v, v)
    assert s.P[6, 6] == 0.04
    np.testing.assert_allclose(s.P[15:18, 15:18], np.eye(3) * 1e-8, atol=EXACT)  # planar: gravity pinned


def test_a_short_window_waits_and_one_the_imu_does_not_cover_slides(make_state, still_imu):
    o = make_state(use_imu=True)
    o.startup.scans = _window(5)  # 0.4 s: shorter than init_window_s
    o.imu.add(still_imu(0, 3 * NS))
    assert try_start(o) is None and len(o.startup.scans) == 5
    o.startup.scans = _window(12)  # 1.1 s, but the IMU starts after the window's first scan
    o.imu.batches = [still_imu(NS + NS // 20, 3 * NS)]
    assert try_start(o) is None and [w.out_index for w in o.startup.scans] == list(range(1, 12))
    assert o.nav.state is None


def test_a_covered_window_starts_the_imu_state_standing(make_state, still_imu):
    o = make_state(use_imu=True)
    o.startup.scans = win = _window(12)
    o.imu.add(still_imu(0, 3 * NS))
    assert try_start(o) == win
    assert o.startup.bootstrap.static and o.startup.scans == [] and o.events == []
    np.testing.assert_allclose(o.nav.g_world, [0.0, 0.0, -G], atol=1e-9)
    assert o.nav.state.stamp_ns == win[0].t_prev_ns
    o.startup.scans = _window(12, t0_ns=5 * NS)  # a second start is a restart: an event says how
    o.imu.add(still_imu(3 * NS + 5_000_000, 7 * NS))
    try_start(o)
    assert [e["kind"] for e in o.events] == ["recovered"]


def test_the_replay_registers_the_window_again_on_a_fresh_map_counted_once(make_state, still_state):
    o = make_state(use_imu=True)
    for w in _window(3):
        o.track.append(w.stamp_ns, w.pose)
    o.stats.used, o.stats.lidar_only_scans, o.stats.degenerate = 3, 3, 1
    o.nav.state = still_state(NS - NS // 10)
    o.reg = "the LiDAR-only map"
    calls = []

    def step(cloud, t_prev, t_ref):
        calls.append((t_prev, t_ref))
        o.track.append(t_ref, np.eye(4))
        o.stats.used += 1
        assert o.reg is None  # a fresh map

    replay(o, _window(3), step)
    assert calls == [(NS - NS // 10, NS), (NS, NS + NS // 10), (NS + NS // 10, NS + 2 * NS // 10)]
    assert list(o.track.stamps_ns) == [NS, NS + NS // 10, NS + 2 * NS // 10]  # replaced, not appended
    assert (o.stats.used, o.stats.lidar_only_scans, o.stats.degenerate) == (3, 0, 1)
    assert o.degeneracy.due == (0, -1)


def test_a_first_window_stuck_at_a_standstill_slides_and_is_replayed_from_its_first_scan(make_state, still_imu):
    """Without wheels, LiDAR-only poses that stand still for 0.7 s and then move at 7.5 m/s misfit an IMU that felt
    no acceleration: the window slides, keeping its scans; a window that fits starts the state, and every scan is
    replayed from the first, at the velocity carried back to it."""
    o = make_state(use_imu=True)
    o.imu.add(still_imu(0, 4 * NS))
    stuck = _window(12)
    for k, w in enumerate(stuck[8:], start=1):
        w.pose[0, 3] = 0.75 * k
    o.startup.scans = stuck
    assert try_start(o) is None and o.nav.state is None
    assert [w.out_index for w in o.startup.held] == [0] and len(o.startup.scans) == 11
    o.startup.scans = _window(12, v_mps=7.5, t0_ns=NS + NS // 10)[:11]
    win = try_start(o)
    assert win is not None and win[0] is stuck[0] and len(win) == 12 and o.startup.held == []
    np.testing.assert_allclose(o.startup.bootstrap.v_start, [7.5, 0.0, 0.0], atol=1e-6)
    assert o.startup.bootstrap.residual_m < 1e-6
