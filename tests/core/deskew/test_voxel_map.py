"""The growing voxel map keeps one point per voxel: the first to arrive, across scans."""

import numpy as np
import pytest

from lio_cli.core.deskew.voxel_map import VoxelMap


def test_one_point_per_voxel_first_come_across_scans():
    m = VoxelMap(0.5)
    m.add(np.array([[0.1, 0.1, 0.1], [0.2, 0.3, 0.4], [0.6, 0.1, 0.1], [np.nan, 0.0, 0.0], [-0.1, 0.1, 0.1]]))
    assert len(m) == 3
    m.add(np.array([[0.4, 0.4, 0.4], [5.2, -3.1, 1.0]]))  # the first voxel is taken; a new one
    np.testing.assert_allclose(m.points(), [[-0.1, 0.1, 0.1], [0.1, 0.1, 0.1], [0.6, 0.1, 0.1], [5.2, -3.1, 1.0]],
                               rtol=1e-6)
    assert m.points().dtype == np.float32


def test_a_dense_cloud_thins_to_its_voxel_count():
    rng = np.random.default_rng(0)
    pts = rng.uniform(0, 10, (20000, 3))
    m = VoxelMap(1.0)
    m.add(pts[:10000])
    m.add(pts[10000:])
    assert len(m) == 1000 and len(m.points()) == 1000
    keys = np.floor(m.points() / 1.0).astype(int)
    assert len(np.unique(keys, axis=0)) == 1000


def test_far_points_are_counted_not_wrapped():
    m = VoxelMap(0.1)
    m.add(np.array([[1e6, 0.0, 0.0], [1.0, 1.0, 1.0]]))
    assert len(m) == 1 and m.outside == 1
    with pytest.raises(ValueError):
        VoxelMap(0.0)
