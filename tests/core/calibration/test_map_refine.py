"""Map refinement of a calibration's LiDAR poses: thinning, de-skew through the gyro, and scans pulled onto one
map of all of them."""

from __future__ import annotations

import numpy as np

from lio_cli.core.calibration.map_refine import Sweep, _deskewed, refine_poses, thin_sweep
from lio_cli.core.calibration.signals import GyroOrientation
from lio_cli.geometry import make_pose, so3_exp, so3_log

S = 1_000_000_000


def test_thinning_keeps_the_first_point_of_each_voxel_with_its_own_time():
    pts = np.array([[0.01, 0.01, 0.01], [0.02, 0.02, 0.02], [0.51, 0.0, 0.0], [0.05, 0.0, 0.0], [0.6, 0.1, 0.0]])
    stamps = np.array([100, 200, 300, 400, 500]) + 10 * S
    sw = thin_sweep(pts, stamps, 10 * S + 500, voxel_m=0.5)
    assert np.allclose(sw.points, pts[[0, 2]])  # firing order kept, one point per 0.5 m voxel
    assert np.allclose(sw.dt_s, [-400e-9, -200e-9])
    assert sw.points.dtype == np.float32 and sw.end_ns == 10 * S + 500


def test_deskew_turns_each_point_by_the_gyro_rotation_since_its_capture_through_the_mounting():
    w = np.array([0.3, -0.2, 2.5])  # rad/s in the IMU frame, constant
    stamps = np.arange(0, 2 * S, 5_000_000)
    gyro = GyroOrientation(stamps, np.tile(w, (len(stamps), 1)))
    R_li = so3_exp(np.array([0.4, -0.2, 1.2]))  # IMU -> LiDAR
    rng = np.random.default_rng(3)
    world = rng.uniform(-10, 10, (200, 3))  # fixed points; the LiDAR turns about its origin
    end = S
    dt = -rng.uniform(0, 0.1, 200)
    w_lidar = R_li @ w
    # the LiDAR's orientation at time t (relative to the start) is exp(w_lidar t): a point seen then is R(t)^T X
    seen = np.stack([so3_exp(w_lidar * (1.0 + d)).T @ x for d, x in zip(dt, world)])
    sw = Sweep(end, seen.astype(np.float32), dt.astype(np.float32))
    v = np.array([1.0, 0.5, 0.0])  # and a constant velocity in the end frame moves each point by v dt
    out = _deskewed(sw, gyro, R_li, 0.0, v)
    expect = world @ so3_exp(w_lidar * 1.0) + dt[:, None] * v  # R(end)^T X, as rows
    assert np.abs(out - expect).max() < 2e-5  # float32 points at 10 m


def _room_points(rng, n=6000):
    """Points on a 10 x 8 x 3 m room's floor, ceiling and walls, plus a pillar and a table top."""
    faces = []
    for axis, value, lo, hi in ((2, 0.0, (-5, -4), (5, 4)), (2, 3.0, (-5, -4), (5, 4)), (0, -5.0, (-4, 0), (4, 3)),
                                (0, 5.0, (-4, 0), (4, 3)), (1, -4.0, (-5, 0), (5, 3)), (1, 4.0, (-5, 0), (5, 3)),
                                (0, 1.5, (-1, 0), (-0.5, 3)), (2, 0.8, (2, 1), (3.5, 2.5))):
        uv = rng.uniform(lo, hi, (n // 8, 2))
        p = np.insert(uv, axis, value, axis=1)
        faces.append(p)
    return np.concatenate(faces)


def test_scans_placed_with_noisy_poses_are_pulled_back_onto_one_map():
    rng = np.random.default_rng(7)
    n = 40
    stamps = (np.arange(n) * 0.1 * S).astype(np.int64) + S
    truth = np.stack([make_pose(so3_exp(np.array([0.08 * np.sin(k / 5), 0.06 * np.cos(k / 7), 0.15 * k])),
                                np.array([-2 + 0.1 * k, 0.5 * np.sin(k / 6), 1.4])) for k in range(n)])
    sweeps = {}
    for k in range(n):
        world = _room_points(rng)
        local = (world - truth[k, :3, 3]) @ truth[k, :3, :3]
        local += rng.normal(0, 0.01, local.shape)  # 1 cm range noise
        sweeps[int(stamps[k])] = Sweep(int(stamps[k]), local.astype(np.float32), np.zeros(len(local), np.float32))
    noisy = truth.copy()
    for k in range(1, n):
        noisy[k, :3, :3] = so3_exp(np.radians(rng.normal(0, 0.5, 3))) @ truth[k, :3, :3]
        noisy[k, :3, 3] += rng.normal(0, 0.03, 3)
    gyro = GyroOrientation(np.arange(0, 6 * S, 5_000_000), np.zeros((1200, 3)))  # still within each sweep

    def errors(poses):  # relative to the first pose (the gauge)
        rel = np.linalg.inv(poses[0]) @ poses
        rel_t = np.linalg.inv(truth[0]) @ truth
        rot = [np.degrees(np.linalg.norm(so3_log(a[:3, :3] @ b[:3, :3].T))) for a, b in zip(rel, rel_t)]
        return np.sqrt(np.mean(np.square(rot))), np.sqrt(np.mean(np.sum((rel[:, :3, 3] - rel_t[:, :3, 3]) ** 2, 1)))

    rot0, pos0 = errors(noisy)
    poses = noisy
    for _ in range(3):
        poses, moved = refine_poses(stamps, poses, sweeps, gyro, np.eye(3), 0.0, 0.2)
        assert moved == n
    rot1, pos1 = errors(poses)
    assert rot0 > 0.6 and pos0 > 0.04  # what the noise gave
    assert rot1 < rot0 / 3 and pos1 < pos0 / 3, (rot0, rot1, pos0, pos1)


def test_a_scan_with_nothing_to_pair_keeps_its_pose():
    stamps = np.array([S, S + S // 10], np.int64)
    poses = np.stack([np.eye(4), np.eye(4)])
    far = np.full((100, 3), 50.0, np.float32) + np.arange(100, dtype=np.float32)[:, None]  # a line: no planes at all
    sweeps = {int(s): Sweep(int(s), far, np.zeros(100, np.float32)) for s in stamps}
    gyro = GyroOrientation(np.arange(0, 2 * S, 5_000_000), np.zeros((400, 3)))
    out, moved = refine_poses(stamps, poses, sweeps, gyro, np.eye(3), 0.0, 0.2)
    assert moved == 0 and np.array_equal(out, poses)


def test_the_deskew_velocity_spans_several_scans_so_pose_noise_does_not_feed_back():
    """A walk (1.2 m/s, a 2 Hz vertical bob of 3 cm) whose poses scatter 2 cm: the velocity each scan is de-skewed
    with is its mean over the scan (centred on the scan's middle). From the step before alone it scattered by
    two poses' noise over 0.1 s (0.28 m/s, and de-skewed scans carried it back into the poses); over 0.3 s a
    third of that along the walk, and half across the bob (which 0.3 s follows only half-way); a constant
    acceleration is followed exactly."""
    from lio_cli.core.calibration.map_refine import _velocities

    rng = np.random.default_rng(11)
    n = 300
    t = np.arange(n) * 0.1
    stamps = (t * S).astype(np.int64) + S
    yaw = 0.5 * np.sin(2 * np.pi * 0.3 * t)
    truth = np.stack([make_pose(so3_exp(np.array([0.0, 0.0, y])), np.zeros(3)) for y in yaw])

    def position(s):
        return np.stack([1.2 * s, 0.1 * np.sin(s), 0.03 * np.sin(2 * np.pi * 2.0 * s)], axis=1)

    truth[:, :3, 3] = position(t)
    mid = t - 0.05  # the mean velocity over the scan (t - 0.1, t]: the position step over it
    v_true = np.einsum("nji,nj->ni", truth[:, :3, :3], (position(t) - position(t - 0.1)) / 0.1)
    noisy = truth.copy()
    noisy[:, :3, 3] += rng.normal(0.0, 0.02, (n, 3))
    err = np.sqrt(np.mean((_velocities(stamps, noisy) - v_true)[2:-2] ** 2, axis=0))
    err_step = np.sqrt(np.mean((_velocities(stamps, noisy, half=0) - v_true)[2:-2] ** 2, axis=0))
    assert (err_step > 0.25).all() and (err[:2] < 0.4 * err_step[:2]).all() and err[2] < 0.6 * err_step[2], (err, err_step)
    accel = truth.copy()
    accel[:, :3, :3] = np.eye(3)
    accel[:, :3, 3] = np.outer(0.5 * 0.8 * t**2, [1.0, -0.5, 0.2])  # constant acceleration 0.8 m/s^2
    expect = np.outer(0.8 * mid, [1.0, -0.5, 0.2])
    assert np.abs(_velocities(stamps, accel)[2:-1] - expect[2:-1]).max() < 1e-9  # the ends take what there is
