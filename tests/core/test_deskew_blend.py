"""``motion_compensation.deskew`` against the per-point formula it implements: each point moved by the blend
``(1 - a) T_k + a T_{k+1}`` of its knot interval's two relative transforms, whatever the points' order."""

import numpy as np

from lio_cli.core.motion_compensation import deskew
from lio_cli.geometry import inv_pose, make_pose, so3_exp

KNOTS = np.arange(0, 100_000_001, 5_000_000, dtype=np.int64)  # 21 knots over a 0.1 s sweep


def _sweep():
    rng = np.random.default_rng(11)
    m = len(KNOTS)
    rotvecs = np.column_stack([0.02 * np.sin(np.arange(m)), np.full(m, 0.05), np.linspace(0.0, 0.3, m)])
    poses = np.stack([make_pose(R, [0.15 * k, 0.02 * k * k, 0.01]) for k, R in enumerate(so3_exp(rotvecs))])
    points = rng.normal(0.0, 12.0, (4000, 3))
    stamps = np.sort(rng.integers(-2_000_000, 102_000_000, len(points))).astype(np.int64)  # a few beyond the ends
    T_base_lidar = make_pose(so3_exp(np.array([0.0, 0.0, 0.3])), [0.1, -0.05, 0.2])
    return points, stamps, poses, T_base_lidar


def _per_point(points, stamps, poses, t_ref_ns, T_base_lidar):
    ref = poses[int(np.flatnonzero(KNOTS == t_ref_ns)[0])]
    rel = inv_pose(ref)[None] @ poses @ T_base_lidar
    out = np.empty_like(points)
    for i, (p, t) in enumerate(zip(points, stamps)):
        k = min(max(int(np.searchsorted(KNOTS, t, side="right")) - 1, 0), len(KNOTS) - 2)
        a = min(max((t - KNOTS[k]) / (KNOTS[k + 1] - KNOTS[k]), 0.0), 1.0)
        M = (1.0 - a) * rel[k] + a * rel[k + 1]
        out[i] = M[:3, :3] @ p + M[:3, 3]
    return out


def test_deskew_is_the_per_point_blend_at_either_reference_knot():
    points, stamps, poses, T_bl = _sweep()
    for t_ref in (KNOTS[-1], KNOTS[0], KNOTS[7]):
        got = deskew(points, stamps, KNOTS, poses, int(t_ref), T_bl)
        assert got.shape == points.shape and got.flags["C_CONTIGUOUS"]
        assert np.abs(got - _per_point(points, stamps, poses, t_ref, T_bl)).max() < 1e-12


def test_deskew_does_not_depend_on_the_points_order():
    points, stamps, poses, T_bl = _sweep()
    perm = np.random.default_rng(5).permutation(len(points))
    ordered = deskew(points, stamps, KNOTS, poses, int(KNOTS[-1]), T_bl)
    shuffled = deskew(points[perm], stamps[perm], KNOTS, poses, int(KNOTS[-1]), T_bl)
    assert np.abs(shuffled - ordered[perm]).max() < 1e-12


def test_points_on_the_knots_and_intervals_without_points_blend_as_each_point_alone():
    points, _, poses, T_bl = _sweep()
    # time-ordered stamps: runs of points exactly on knots, and nothing between knots 5 and 12
    stamps = np.sort(np.concatenate([np.repeat(KNOTS, 100), KNOTS[:5].repeat(50) + 1_000_000,
                                     KNOTS[12:].repeat(40) - 1]))[:len(points)].astype(np.int64)
    pts = points[:len(stamps)]
    got = deskew(pts, stamps, KNOTS, poses, int(KNOTS[-1]), T_bl)
    assert np.abs(got - _per_point(pts, stamps, poses, KNOTS[-1], T_bl)).max() < 1e-12
