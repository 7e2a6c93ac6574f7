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


def test_many_scans_keep_first_come_points_as_a_set_of_keys_would():
    rng = np.random.default_rng(1)
    m, seen, expected = VoxelMap(0.1), set(), []
    for _ in range(12):  # ~150 000 voxels: the sorted keys are merged several times on the way
        pts = rng.uniform(-3, 3, (20000, 3)) + rng.uniform(-2, 2, 3)
        m.add(pts)
        ijk = np.floor(pts / 0.1).astype(np.int64)
        _, first = np.unique(ijk, axis=0, return_index=True)
        for i in sorted(first, key=lambda i: tuple(ijk[i])):
            if tuple(ijk[i]) not in seen:
                seen.add(tuple(ijk[i]))
                expected.append(pts[i])
    assert len(m) == len(seen) > 1 << 16
    got = m.points().astype(np.float64)
    assert sorted(map(tuple, np.floor(got / 0.1).astype(np.int64))) == sorted(seen)
    np.testing.assert_allclose(np.sort(got, axis=0), np.sort(np.array(expected), axis=0), rtol=1e-6)
