"""De-skew against a scan simulated with known motion; fusion on hand-checkable cases; degeneracy."""

import numpy as np

from lio_cli.core.motion_compensation import constant_velocity_knots, deskew, to_base
from lio_cli.core.odometry.filter import complementary_update, ekf_body_velocity_update, ekf_pose_update, position_noise
from lio_cli.geometry import inv_pose, make_pose, so3_exp, transform_points
from lio_cli.core.imu import NavState
from lio_cli.core.odometry.degeneracy import CLEAR_MARGIN, analyse_degeneracy, degenerate_directions

DESKEW_TOL_M = 1e-6


def _room(rng, n=4000):
    """Points on the walls, floor and ceiling of a 10 x 8 x 3 m box."""
    pts = rng.uniform([-5, -4, 0], [5, 4, 3], (n, 3))
    face = rng.integers(0, 6, n)
    pts[face == 0, 0], pts[face == 1, 0] = -5, 5
    pts[face == 2, 1], pts[face == 3, 1] = -4, 4
    pts[face == 4, 2], pts[face == 5, 2] = 0, 3
    return pts


def _motion(t):
    """T_world_base at time t (s): fast yaw plus forward motion."""
    return make_pose(so3_exp(np.array([0.05 * t, 0.0, 3.0 * t])), np.array([1.2 * t, 0.3 * t, 0.0]))


def test_deskew_with_true_motion_equals_scan_from_standing_sensor():
    rng = np.random.default_rng(0)
    world = _room(rng)
    T_base_lidar = make_pose(so3_exp(np.array([0.0, 0.1, 0.2])), np.array([0.2, 0.0, 0.4]))
    t = np.sort(rng.uniform(0, 0.1, len(world)))
    stamps = np.round(t * 1e9).astype(np.int64)
    # raw scan: each point seen from the sensor pose at its own instant
    raw = np.array([transform_points(inv_pose(_motion(tj) @ T_base_lidar), p) for tj, p in zip(t, world)])
    knots_t = np.linspace(0, 0.1, 41)
    knots = np.stack([_motion(x) for x in knots_t])
    out = deskew(raw, stamps, np.round(knots_t * 1e9).astype(np.int64), knots, int(0.1e9), T_base_lidar)
    expected = transform_points(inv_pose(_motion(0.1)), world)  # a base standing still at the scan's end
    # piecewise interpolation between 2.5 ms knots of a 3 rad/s motion: sub-millimetre
    np.testing.assert_allclose(out, expected, atol=1e-3)
    skewed = to_base(raw, T_base_lidar)
    assert np.abs(skewed - expected).max() > 0.5  # the raw scan really was skewed


def test_deskew_static_is_identity():
    rng = np.random.default_rng(1)
    pts = rng.normal(size=(100, 3))
    stamps = np.arange(100, dtype=np.int64) * 1000
    out = deskew(pts, stamps, np.array([0, 10**6]), np.stack([np.eye(4), np.eye(4)]), 10**6, np.eye(4))
    np.testing.assert_allclose(out, pts, atol=DESKEW_TOL_M)


def test_constant_velocity_over_a_zero_length_scan_gives_finite_points():
    """Every point at the header stamp (``--point-time none``) on the first scan: a 0 ns interval, no NaN."""
    rng = np.random.default_rng(2)
    pts = rng.normal(size=(50, 3))
    delta = make_pose(so3_exp(np.array([0.0, 0.0, 0.1])), np.array([0.2, 0.0, 0.0]))
    knots, poses = constant_velocity_knots(delta, 10**6, 10**6)
    out = deskew(pts, np.full(50, 10**6, np.int64), knots, poses, 10**6, np.eye(4))
    np.testing.assert_allclose(out, pts, atol=DESKEW_TOL_M)  # all at the reference instant: nothing moves


def _state(pvar=0.01, rvar=1e-4):
    P = np.eye(18) * 1e-6
    P[0:3, 0:3] = np.eye(3) * rvar
    P[3:6, 3:6] = np.eye(3) * pvar
    return NavState(0, np.eye(3), np.zeros(3), np.zeros(3), np.zeros(3), np.zeros(3), P)


def test_ekf_equal_variances_moves_halfway():
    s = _state(pvar=0.01)
    meas = make_pose(None, np.array([0.2, -0.1, 0.05]))
    ekf_pose_update(s, meas, rot_sigma_rad=0.01, pos_cov=np.eye(3) * 0.01)
    np.testing.assert_allclose(s.p, [0.1, -0.05, 0.025], atol=1e-9)
    np.testing.assert_allclose(np.diag(s.P)[3:6], 0.005, atol=1e-9)  # variance halves


def test_ekf_ignores_measurement_along_degenerate_direction():
    s = _state(pvar=1e-4)
    d = np.array([1.0, 0.0, 0.0])
    cov = position_noise(0.01, [d], 100.0)
    ekf_pose_update(s, make_pose(None, np.array([0.5, 0.2, 0.0])), 0.01, cov)
    assert abs(s.p[0]) < 1e-3  # along the corridor: keeps the prediction
    np.testing.assert_allclose(s.p[1], 0.2 * 1e-4 / (1e-4 + 1e-4), atol=1e-9)  # across: normal update


def test_ekf_position_error_corrects_velocity_through_correlation():
    s = _state(pvar=0.01)
    s.P[3:6, 6:9] = s.P[6:9, 3:6] = np.eye(3) * 0.005
    s.P[6:9, 6:9] = np.eye(3) * 0.01
    ekf_pose_update(s, make_pose(None, np.array([0.2, 0.0, 0.0])), 0.01, np.eye(3) * 0.01)
    # K_v = P_vp / (P_pp + R) = 0.005 / 0.02 = 0.25
    np.testing.assert_allclose(s.v, [0.05, 0.0, 0.0], atol=1e-9)


def test_ekf_wheel_velocity_update():
    s = _state()
    s.P[6:9, 6:9] = np.eye(3) * 0.04
    s.R = so3_exp(np.array([0.0, 0.0, np.pi / 2]))  # facing +y
    ekf_body_velocity_update(s, np.array([1.0, 0.0, 0.0]), np.array([0.2, 0.2, 0.2]))
    # body forward is world +y; K = 0.04 / (0.04 + 0.04) = 0.5
    np.testing.assert_allclose(s.v, [0.0, 0.5, 0.0], atol=1e-6)


def test_complementary_filter_follows_lecture_formula():
    s = _state()
    theta_scan = 0.1
    meas = make_pose(so3_exp(np.array([0.0, 0.0, theta_scan])), np.array([1.0, 0.0, 0.0]))
    complementary_update(s, meas, alpha=0.98, dt_s=0.1, R_base_imu=np.eye(3), degenerate_dirs_world=[])
    yaw = np.arctan2(s.R[1, 0], s.R[0, 0])
    np.testing.assert_allclose(yaw, 0.98 * theta_scan, atol=1e-12)
    np.testing.assert_allclose(s.p, [0.98, 0.0, 0.0], atol=1e-12)
    np.testing.assert_allclose(s.v, [9.8, 0.0, 0.0], atol=1e-9)  # position correction over 0.1 s


def test_corridor_is_degenerate_along_its_axis_and_room_is_not():
    rng = np.random.default_rng(2)
    n = 3000
    x = rng.uniform(-20, 20, n)
    side = rng.integers(0, 4, n)
    y = np.where(side == 0, -1.5, np.where(side == 1, 1.5, rng.uniform(-1.5, 1.5, n)))
    z = np.where(side == 2, 0.0, np.where(side == 3, 2.5, rng.uniform(0, 2.5, n)))
    dirs = degenerate_directions(np.column_stack([x, y, z]), planar=False, ratio=0.05)
    assert len(dirs) == 1
    assert abs(dirs[0][0]) > 0.99
    assert degenerate_directions(_room(rng), planar=False, ratio=0.05) == []
    # how far from degenerate: the corridor under 1, the room clear by the margin that spaces out the analyses
    assert analyse_degeneracy(np.column_stack([x, y, z]), planar=False, ratio=0.05).margin < 0.2
    room = analyse_degeneracy(_room(rng), planar=False, ratio=0.05)
    assert room.directions == [] and room.margin > CLEAR_MARGIN


def test_the_degeneracy_analysis_thins_any_scan_over_8192_points_to_at_most_that(monkeypatch):
    """A 16-beam x 1024 scan (16191 points in range) was analysed whole, at twice the cost of a 16384-point one;
    every n-th point now keeps each scan at 8192 or fewer, and the corridor is still found."""
    from lio_cli.core.odometry import degeneracy

    built = []
    real = degeneracy.ckdtree_class()
    monkeypatch.setattr(degeneracy, "ckdtree_class", lambda: lambda pts, **kw: built.append(len(pts)) or real(pts, **kw))
    rng = np.random.default_rng(5)
    for n in (8192, 8193, 16191, 16384, 40000):
        x = rng.uniform(-20, 20, n)
        side = rng.integers(0, 4, n)
        y = np.where(side == 0, -1.5, np.where(side == 1, 1.5, rng.uniform(-1.5, 1.5, n)))
        z = np.where(side == 2, 0.0, np.where(side == 3, 2.5, rng.uniform(0, 2.5, n)))
        dirs = degenerate_directions(np.column_stack([x, y, z]), planar=False, ratio=0.05)
        assert len(dirs) == 1 and abs(dirs[0][0]) > 0.99
    assert built == [8192, 4097, 8096, 8192, 8000]
