"""Scan registration's voxelisation: kiss-icp's double voxelisation, dense scans thinned to max_source_points."""

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
