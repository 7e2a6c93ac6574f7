"""Scan registration: kiss-icp's double voxelisation, dense scans thinned to max_source_points, coarse-to-fine ICP."""

import numpy as np
from kiss_icp.voxelization import voxel_down_sample

from lio_cli.config.odom import RegistrationConfig
from lio_cli.core.odometry.registration import ScanRegistration


def _ground(side_m: float, spacing_m: float = 0.5) -> np.ndarray:
    """A flat square of ground points on a regular grid, centred on the sensor."""
    g = np.arange(-side_m / 2, side_m / 2, spacing_m)
    x, y = np.meshgrid(g, g)
    return np.column_stack([x.ravel(), y.ravel(), np.full(x.size, -1.0)])


def _reg(max_source_points: int | None = 600) -> ScanRegistration:
    return ScanRegistration(RegistrationConfig(max_source_points=max_source_points), 1.0, imu_prior=True, planar=False,
                            fixed_correspondence_m=0.5)


def test_a_sparse_scan_keeps_kiss_icps_double_voxelisation():
    points = _ground(30.0)  # 2.5 m voxels over 30 m: 144 registered points, under the budget
    frame, source = _reg().downsample(points)
    np.testing.assert_array_equal(frame, voxel_down_sample(points, 0.5))
    np.testing.assert_array_equal(source, voxel_down_sample(frame, 2.5))
    assert len(source) == 144


def test_a_dense_scan_registers_about_the_point_budget():
    points = _ground(120.0)  # 2.5 m voxels over 120 m: 2304 points, 3.8x the budget
    frame, source = _reg().downsample(points)
    np.testing.assert_array_equal(frame, voxel_down_sample(points, 0.5))  # the map's points are not thinned
    assert len(voxel_down_sample(frame, 2.5)) == 2304
    budget = 600
    assert 0.8 * budget <= len(source) <= 1.2 * budget  # about: the grown voxels fall on the grid unevenly
    # the thinned points still cover the whole scan, not a part of it
    np.testing.assert_allclose(source[:, :2].min(axis=0), [-60.0, -60.0], atol=5.0)
    np.testing.assert_allclose(source[:, :2].max(axis=0), [59.5, 59.5], atol=5.0)
    # lio odom's default: no limit, kiss-icp's double voxelisation whatever the scan
    assert len(_reg(None).downsample(points)[1]) == 2304


def _scene(rng: np.random.Generator) -> np.ndarray:
    """A street: ground, two facades along x, and boxes, sampled densely (a car scan's structure)."""
    n = 60_000
    ground = np.column_stack([rng.uniform(-60, 60, n), rng.uniform(-15, 15, n), np.full(n, -1.5)])
    walls = np.column_stack([rng.uniform(-60, 60, n), np.where(rng.random(n) < 0.5, -15.0, 15.0), rng.uniform(-1.5, 8, n)])
    boxes = []
    for cx in range(-50, 60, 10):  # 1.5 m cubes' faces across the street
        m = 4000
        face = rng.integers(0, 3, m)
        p = rng.uniform(-0.75, 0.75, (m, 3))
        p[np.arange(m), face] = np.where(rng.random(m) < 0.5, -0.75, 0.75)
        boxes.append(p + [cx, 5.0 * np.sign(cx + 0.5), -0.75])
    return np.vstack([ground, walls, *boxes])


def _moved(points: np.ndarray, T: np.ndarray) -> np.ndarray:
    return points @ T[:3, :3].T + T[:3, 3]


def test_a_dense_scan_is_registered_coarse_to_fine_to_the_truth():
    rng = np.random.default_rng(0)
    scene = _scene(rng)
    T_true = np.eye(4)
    c, s = np.cos(0.01), np.sin(0.01)
    T_true[:2, :2] = [[c, -s], [s, c]]
    T_true[:3, 3] = [0.12, -0.06, 0.03]
    scan = _moved(scene, np.linalg.inv(T_true))  # the same street seen from T_true

    def register(rc: RegistrationConfig) -> tuple[np.ndarray, int]:
        reg = ScanRegistration(rc, 1.0, imu_prior=True, planar=False, fixed_correspondence_m=0.5)
        frame, _ = reg.downsample(scene)
        reg.accept(None, frame, np.eye(4))
        source = reg.downsample(scan)[1]
        return reg.register(source, np.eye(4)), len(source)

    # one refining iteration on every point suffices after the sparse copy's alignment...
    T, n = register(RegistrationConfig(coarse_points=200, refine_iterations=1))
    assert n > 400  # dense enough to take the coarse-to-fine path
    np.testing.assert_allclose(T[:3, 3], T_true[:3, 3], atol=0.01)
    np.testing.assert_allclose(T[:3, :3], T_true[:3, :3], atol=1e-3)
    # ...where one iteration on every point alone stops far from the truth
    T1, _ = register(RegistrationConfig(coarse_points=None, max_iterations=1))
    assert np.linalg.norm(T1[:3, 3] - T_true[:3, 3]) > 0.03
    # and all points to convergence land where coarse-to-fine does
    T_full, _ = register(RegistrationConfig(coarse_points=None))
    np.testing.assert_allclose(T[:3, 3], T_full[:3, 3], atol=0.005)


def test_a_sparse_scan_registers_all_its_points_at_once():
    rng = np.random.default_rng(1)
    scene = _scene(rng)
    scan = _moved(scene, np.array([[1, 0, 0, -0.1], [0, 1, 0, 0.05], [0, 0, 1, 0], [0, 0, 0, 1.0]]))

    def register(coarse: int | None) -> np.ndarray:
        reg = ScanRegistration(RegistrationConfig(coarse_points=coarse, refine_iterations=1), 1.0, imu_prior=True,
                               planar=False, fixed_correspondence_m=0.5)
        reg.accept(None, reg.downsample(scene)[0], np.eye(4))
        return reg.register(reg.downsample(scan)[1], np.eye(4))

    # under twice the coarse budget: the very ICP of every point, without the refining cap (kiss-icp's threads
    # may sum in another order: 1e-17); a budget it exceeds takes the other path
    np.testing.assert_allclose(register(5000), register(None), rtol=0, atol=1e-12)
    assert np.abs(register(100) - register(None)).max() > 1e-6


def test_a_cap_of_few_iterations_registers_every_point_at_once():
    rng = np.random.default_rng(2)
    scene = _scene(rng)
    scan = _moved(scene, np.array([[1, 0, 0, -0.1], [0, 1, 0, 0.05], [0, 0, 1, 0], [0, 0, 0, 1.0]]))

    def register(coarse: int | None, iterations: int) -> np.ndarray:
        reg = ScanRegistration(RegistrationConfig(coarse_points=coarse, refine_iterations=5), 1.0, imu_prior=True,
                               planar=False, fixed_correspondence_m=0.5)
        reg.accept(None, reg.downsample(scene)[0], np.eye(4))
        return reg.register(reg.downsample(scan)[1], np.eye(4), iterations=iterations)

    # lio deskew's cap of 5: no coarse stage to add to it; a cap of 10 takes one
    np.testing.assert_allclose(register(200, 5), register(None, 5), rtol=0, atol=1e-12)
    assert np.abs(register(200, 10) - register(None, 10)).max() > 1e-6


def _room(rng: np.random.Generator) -> np.ndarray:
    """Points on a floor and three walls: a scene ICP pins in every direction."""
    n = 1500
    floor = np.column_stack([rng.uniform(-8, 8, n), rng.uniform(-8, 8, n), np.full(n, -1.0)])
    wall_x = np.column_stack([np.full(n, 6.0), rng.uniform(-8, 8, n), rng.uniform(-1, 2, n)])
    wall_y = np.column_stack([rng.uniform(-8, 8, n), np.full(n, 5.0), rng.uniform(-1, 2, n)])
    wall_b = np.column_stack([rng.uniform(-8, 8, n), np.full(n, -7.0), rng.uniform(-1, 2, n)])
    return np.vstack([floor, wall_x, wall_y, wall_b])


def test_the_bindings_give_kiss_icps_python_wrappers_result():
    from kiss_icp.mapping import VoxelHashMap
    from kiss_icp.registration import Registration

    rng = np.random.default_rng(3)
    scene = _room(rng)
    rc = RegistrationConfig(threads=1)  # one thread: the same sums in the same order
    reg = ScanRegistration(rc, 0.5, imu_prior=True, planar=False, fixed_correspondence_m=0.5)
    frame, source = reg.downsample(scene)
    reg.accept(None, frame, np.eye(4))
    ref_map = VoxelHashMap(0.5, rc.max_range_m, rc.max_points_per_voxel)
    ref_map.update(frame, np.eye(4))
    np.testing.assert_array_equal(reg.map.point_cloud(), ref_map.point_cloud())
    guess = np.eye(4)
    guess[:3, 3] = [0.12, -0.08, 0.03]  # the scan seen from the origin, guessed a few cm off
    got = reg.register(source, guess)
    want = Registration(20, rc.convergence, 1).align_points_to_map(source, ref_map, guess, 0.5, 0.5 / 3.0)
    # equal to rounding: a worker that ran other tests first sums in another order
    np.testing.assert_allclose(got, want, rtol=0, atol=1e-9)
    np.testing.assert_allclose(got[:3, 3], 0.0, atol=0.01)  # and it is right: back at the origin


def test_loading_the_registration_leaves_kiss_icps_pydantic_configuration_unloaded():
    import subprocess
    import sys

    code = ("import sys, lio_cli.core.odometry.registration\n"
            "print(sorted(m for m in sys.modules if m.startswith(('pydantic_settings', 'kiss_icp.config'))))")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True).stdout
    assert out.strip() == "[]"


def test_the_map_stays_bounded_over_a_long_drive():
    # 600 scans 2 m apart along a 1.2 km street: the map keeps only what lies within max_range_m of the sensor
    rng = np.random.default_rng(3)
    reg = ScanRegistration(RegistrationConfig(max_range_m=40.0), 1.0, imu_prior=True, planar=False,
                           fixed_correspondence_m=0.5)
    sizes = []
    for k in range(600):
        x = 2.0 * k
        n = 3000  # the street around the sensor, in the world frame: ground and two facades
        ground = np.column_stack([rng.uniform(x - 40, x + 40, n), rng.uniform(-12, 12, n), np.full(n, -1.5)])
        walls = np.column_stack([rng.uniform(x - 40, x + 40, n), np.where(rng.random(n) < 0.5, -12.0, 12.0),
                                 rng.uniform(-1.5, 6.0, n)])
        pose = np.eye(4)
        pose[0, 3] = x
        frame, _ = reg.downsample(np.vstack([ground, walls]) - [x, 0.0, 0.0])  # in the sensor's frame
        reg.accept(None, frame, pose)
        sizes.append(len(reg.map.point_cloud()))
    cloud = reg.map.point_cloud()
    # nothing behind the last 40 m (a voxel's first point decides: a voxel's diagonal more at most)
    assert cloud[:, 0].min() >= 2.0 * 599 - 40.0 - 1.8
    # the size levels off once the sensor has driven max_range_m: the last 400 scans within 10 % of each other
    steady = np.array(sizes[200:])
    assert steady.max() <= 1.1 * steady.min()
    assert sizes[-1] < 0.2 * sizes[0] * 600  # far from every scan's points kept
