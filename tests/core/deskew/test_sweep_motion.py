"""Poses within a sweep (cubic spline, gyro) and points de-skewed into the sensor frame, against known motion."""

import numpy as np
import pytest

from lio_cli.core.deskew.sweep_motion import KNOT_STEP_NS, PoseSpline, deskew_to_sensor, gyro_sweep_poses, sweep_knots
from lio_cli.geometry import inv_pose, make_pose, so3_exp, so3_log, transform_points
from lio_cli.model.calibration import Extrinsics
from lio_cli.model.records import ImuBatch
from lio_cli.simulation.scenarios import build_scenario
from lio_cli.simulation.sensors import ImuSpec, synthesize_imu

EXACT = 1e-9
T_BASE_LIDAR = make_pose(so3_exp(np.array([0.02, -0.1, 0.3])), np.array([0.2, 0.05, 0.4]))


def _rot_err_deg(A, B):
    return np.degrees(np.linalg.norm(so3_log(np.einsum("nji,njk->nik", A[:, :3, :3], B[:, :3, :3])), axis=1))


def _screw(t_s):
    """A constant twist: 2.5 rad/s about a tilted axis, 1.3 m/s along a fixed world direction."""
    t = np.atleast_1d(t_s)
    axis = np.array([0.3, -0.2, 0.93]) / np.linalg.norm([0.3, -0.2, 0.93])
    R = so3_exp(np.outer(2.5 * t, axis))
    p = np.outer(t, [1.0, 0.8, 0.2]) + [3.0, -1.0, 0.5]
    T = np.zeros((len(t), 4, 4))
    T[:, :3, :3], T[:, :3, 3], T[:, 3, 3] = R, p, 1.0
    return T


@pytest.fixture(scope="module")
def handheld():
    return build_scenario("handheld", start="moving").trajectory


def test_cubic_follows_the_handheld_yaw_sweeps_that_linear_interpolation_misses(handheld):
    q = np.arange(1_000_000_000, 19_000_000_000, 1_300_000, dtype=np.int64)
    truth = handheld.poses(q * 1e-9)
    stamps = np.arange(0, 20_000_000_000, 100_000_000, dtype=np.int64)  # a pose per scan, as odometry gives
    poses = handheld.poses(stamps * 1e-9)
    cubic = _rot_err_deg(PoseSpline(stamps, poses).at(q), truth)
    linear = _rot_err_deg(PoseSpline(stamps, poses, cubic=False).at(q), truth)
    assert cubic.max() < 0.5 and np.median(cubic) < 0.15
    assert linear.max() > 1.5 and np.median(linear) > 0.4  # what the cubic is for
    dense = np.arange(0, 20_000_000_000, 10_000_000, dtype=np.int64)  # ground truth at 100 Hz
    assert _rot_err_deg(PoseSpline(dense, handheld.poses(dense * 1e-9)).at(q), truth).max() < 1e-3


def test_a_constant_twist_is_reproduced_exactly_inside_and_beyond_the_ends():
    stamps = np.array([0, 70, 100, 180, 260, 300], dtype=np.int64) * 1_000_000  # uneven spacing
    spline = PoseSpline(stamps, _screw(stamps * 1e-9), extrapolate_ns=50_000_000)
    q = np.array([-50, -10, 0, 35, 100, 222, 300, 333, 350], dtype=np.int64) * 1_000_000
    for mode in (spline, PoseSpline(stamps, _screw(stamps * 1e-9), cubic=False)):
        np.testing.assert_allclose(mode.at(q), _screw(q * 1e-9), atol=EXACT)
        np.testing.assert_allclose(mode.positions(q), _screw(q * 1e-9)[:, :3, 3], atol=EXACT)  # the same, cheaper
        np.testing.assert_array_equal(mode.at(stamps[[4, 1]]), _screw(stamps[[4, 1]] * 1e-9))  # the poses as given
    one = PoseSpline(stamps[:1], _screw(stamps[:1] * 1e-9))
    np.testing.assert_array_equal(one.positions(q), np.repeat(_screw(0.0)[:, :3, 3], len(q), axis=0))


def test_coverage_says_why_a_sweep_is_not_covered():
    stamps = np.array([0, 100, 200, 900, 1000], dtype=np.int64) * 1_000_000
    spline = PoseSpline(stamps, _screw(stamps * 1e-9), extrapolate_ns=20_000_000, max_gap_ns=500_000_000)
    assert spline.uncovered(-20_000_000, 80_000_000) is None
    assert spline.uncovered(-30_000_000, 80_000_000) == "before the trajectory starts"
    assert spline.uncovered(950_000_000, 1_030_000_000) == "after the trajectory ends"
    assert spline.uncovered(300_000_000, 400_000_000) == "in a gap of the trajectory"
    assert spline.uncovered(120_000_000, 190_000_000) is None
    with pytest.raises(ValueError):
        PoseSpline(np.array([0, 0]), _screw(np.zeros(2)))


def test_sweep_knots_span_the_sweep_at_most_a_step_apart():
    k = sweep_knots(1_000, 1_000 + 99_609_375)
    assert k[0] == 1_000 and k[-1] == 1_000 + 99_609_375
    assert np.diff(k).max() <= KNOT_STEP_NS and np.all(np.diff(k) > 0)
    assert list(sweep_knots(5, 5)) == [5]


def test_points_at_the_knots_land_exactly_in_the_sensor_frame_at_the_reference():
    rng = np.random.default_rng(3)
    knots = sweep_knots(0, 100_000_000)
    poses = _screw(knots * 1e-9)
    pick = rng.integers(0, len(knots), 500)
    stamps = knots[pick]
    pts = rng.normal(size=(500, 3)) * 8.0
    for ref in (knots[0], knots[-1]):
        out = deskew_to_sensor(pts, stamps, knots, poses, int(ref), T_BASE_LIDAR)
        T_ref = poses[0 if ref == knots[0] else -1] @ T_BASE_LIDAR
        rel = inv_pose(T_ref)[None] @ poses[pick] @ T_BASE_LIDAR
        expected = np.einsum("nij,nj->ni", rel[:, :3, :3], pts) + rel[:, :3, 3]
        np.testing.assert_allclose(out, expected, atol=EXACT)


def test_a_world_seen_while_moving_is_seen_as_from_a_standing_sensor():
    """Points of a fixed world, each measured from the sensor pose at its own instant, come out as the
    sensor standing at the sweep's end sees them (a broken frame chain or sign is off by metres)."""
    rng = np.random.default_rng(1)
    world = rng.uniform([-6, -6, -1], [6, 6, 3], (3000, 3))
    stamps = np.sort(rng.integers(0, 100_000_000, 3000)).astype(np.int64)
    T_wl = _screw(stamps * 1e-9) @ T_BASE_LIDAR
    raw = np.einsum("nij,nj->ni", inv_pose(T_wl)[:, :3, :3], world) + inv_pose(T_wl)[:, :3, 3]
    knots = sweep_knots(0, 100_000_000)
    out = deskew_to_sensor(raw, stamps, knots, _screw(knots * 1e-9), int(knots[-1]), T_BASE_LIDAR)
    standing = transform_points(inv_pose(_screw(0.1)[0] @ T_BASE_LIDAR), world)
    assert np.abs(raw - standing).max() > 0.5  # the skew is real
    np.testing.assert_allclose(out, standing, atol=2e-4)  # chord of 4 ms knots at 2.5 rad/s


def test_gyro_rotation_and_spline_translation_over_a_sweep(handheld):
    """An ideal IMU on the handheld: the gyro gives the sweep's rotation to 0.003 deg, the spline (poses only
    at the sweep's ends and around) the translation; an IMU gap is refused."""
    T_base_imu = make_pose(so3_exp(np.array([0.02, -0.03, 1.57])), np.array([0.04, -0.02, 0.03]))
    t0, t1 = 7_000_000_000, 7_099_000_000
    data = synthesize_imu(handheld, T_base_imu, ImuSpec(rate_hz=200.0), 6_500_000_000, 7_500_000_000, 0, None)
    imu = ImuBatch("imu", data.stamps_ns, data.gyro_radps, data.accel_mps2)
    scan_ns = np.sort(np.append(np.arange(6_000_000_000, 8_100_000_000, 100_000_000, dtype=np.int64), t1))
    spline = PoseSpline(scan_ns, handheld.poses(scan_ns * 1e-9))
    ext = Extrinsics(T_base_imu, T_BASE_LIDAR)
    knots, poses = gyro_sweep_poses(spline, imu, t0, t1, t1, ext, np.zeros(3))
    truth = handheld.poses(knots * 1e-9)
    rel = lambda P: inv_pose(P[-1])[None] @ P  # noqa: E731 - motion relative to the reference (end)
    assert _rot_err_deg(rel(poses), rel(truth)).max() < 3e-3  # midpoint rule at 200 Hz; the cubic is 0.1 deg off
    assert np.linalg.norm(rel(poses)[:, :3, 3] - rel(truth)[:, :3, 3], axis=1).max() < 2e-3
    gap = ImuBatch("imu", imu.stamps_ns[imu.stamps_ns < t0 + 20_000_000], imu.gyro_radps[imu.stamps_ns < t0 + 20_000_000],
                   imu.accel_mps2[imu.stamps_ns < t0 + 20_000_000])
    assert gyro_sweep_poses(spline, gap, t0, t1, t1, ext, np.zeros(3)) is None
