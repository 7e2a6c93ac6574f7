"""``jobs.odom.map.RunMap``: scans wait for their final pose, replays replace them, the cloud is levelled and holds
one point per voxel of the output frame."""

import numpy as np

from lio_cli.core.deskew.voxel_map import voxel_keys
from lio_cli.geometry import make_pose, so3_exp
from lio_cli.jobs.odom.map import RunMap

VOXEL_M = 0.1


def _wall(x_m: float) -> np.ndarray:
    """A wall of points 5 cm apart at x = ``x_m`` in the base frame."""
    y, z = np.meshgrid(np.arange(-1.0, 1.0, 0.05), np.arange(0.0, 1.0, 0.05))
    return np.column_stack([np.full(y.size, x_m), y.ravel(), z.ravel()])


def test_a_scan_joins_the_map_at_its_final_pose_only():
    m = RunMap(VOXEL_M)
    stamps = [10, 20, 30]
    early = [np.eye(4), make_pose(t=np.array([1.0, 0, 0])), make_pose(t=np.array([2.0, 0, 0]))]
    for s in stamps:
        m.scan(s, _wall(3.0))
    m.settle(stamps, early, 1)  # the first pose is final, the others may still change
    assert (m.scans, m.mapped, sorted(m.pending)) == (1, 1, [20, 30])
    m.scan(20, _wall(3.0) + [0.0, 0.0, 0.5])  # a replay: the scan de-skewed again
    m.scan(30, None)  # ...and the replay failed this one: out of the map
    final = [early[0], make_pose(t=np.array([1.0, 0, 0])), early[2]]
    m.settle(stamps, final, 3)
    assert (m.scans, m.pending) == (2, {})
    pts = m.cloud(np.eye(4)).astype(np.float64)
    xs = np.unique(np.round(pts[:, 0], 6))
    np.testing.assert_allclose(xs, [3.0, 4.0])  # the first scan's wall, the second's moved by its pose
    assert pts[pts[:, 0] > 3.5, 2].min() >= 0.5  # the replayed points, not the first version


def test_the_cloud_is_levelled_and_one_point_per_voxel_of_the_output_frame():
    m = RunMap(VOXEL_M)
    rng = np.random.default_rng(3)
    m.scan(1, rng.uniform(-5, 5, (20000, 3)))
    m.settle([1], [np.eye(4)], 1)
    level = make_pose(so3_exp(np.array([0.04, -0.03, 0.0])))
    pts = m.cloud(level)
    assert pts.dtype == np.float32
    keys, inside = voxel_keys(pts.astype(np.float64), VOXEL_M)
    assert inside.all() and len(np.unique(keys)) == len(pts)  # read back as written: one point per voxel
    internal = m.voxels.points().astype(np.float64) @ level[:3, :3].T
    # every levelled point is one of the internal grid's points, rotated (float32)
    d = np.linalg.norm(internal[:, None, :] - pts[None, :50, :].astype(np.float64), axis=2).min(axis=0)
    assert d.max() < 1e-5
    assert len(pts) <= len(m.voxels)
