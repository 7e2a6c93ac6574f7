"""SO(3)/SE(3)/SE(2) helpers: hypothesis round trips plus deliberate edge cases (tiny and near-pi angles)."""

from __future__ import annotations

import warnings

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from hypothesis.extra.numpy import arrays

from lio_cli import geometry as g

ROT_TOL = 1e-9  # rotation matrices / rotation vectors away from pi
TRANS_TOL_M = 1e-9
NEAR_PI_TOL_RAD = 1e-6  # rotation vectors within 1e-6 of pi are ill-conditioned
SETTINGS = settings(max_examples=60, deadline=None, derandomize=True)

finite = st.floats(-10.0, 10.0, allow_nan=False, allow_infinity=False)
vec3 = arrays(np.float64, 3, elements=finite)
# rotation vectors with angle in [0, pi - 1e-3]: away from the log's branch cut
rotvec = st.builds(
    lambda axis, angle: angle * axis / np.linalg.norm(axis),
    arrays(np.float64, 3, elements=st.floats(-1, 1)).filter(lambda a: np.linalg.norm(a) > 1e-3),
    st.floats(0.0, np.pi - 1e-3),
)
pose = st.builds(lambda r, t: g.make_pose(g.so3_exp(r), t), rotvec, vec3)


@SETTINGS
@given(rotvec)
def test_so3_exp_log_round_trip(phi):
    np.testing.assert_allclose(g.so3_log(g.so3_exp(phi)), phi, atol=ROT_TOL)


@SETTINGS
@given(rotvec)
def test_quaternion_round_trip_and_w_nonnegative(phi):
    R = g.so3_exp(phi)
    q = g.rot_to_quat_xyzw(R)
    assert q[3] >= 0.0
    np.testing.assert_allclose(np.linalg.norm(q), 1.0, atol=ROT_TOL)
    np.testing.assert_allclose(g.quat_xyzw_to_rot(q), R, atol=ROT_TOL)
    np.testing.assert_allclose(g.quat_xyzw_to_rot(-q), R, atol=ROT_TOL)  # q and -q: same rotation


@SETTINGS
@given(pose)
def test_pose_xyz_quat_round_trip(T):
    xyz, q = g.pose_to_xyz_quat(T)
    np.testing.assert_allclose(g.pose_from_xyz_quat(xyz, q), T, atol=ROT_TOL)


@SETTINGS
@given(pose, arrays(np.float64, (5, 3), elements=finite))
def test_inverse_undoes_pose_and_matches_numpy(T, pts):
    Ti = g.inv_pose(T)
    np.testing.assert_allclose(Ti @ T, np.eye(4), atol=ROT_TOL)
    np.testing.assert_allclose(Ti, np.linalg.inv(T), atol=ROT_TOL)
    np.testing.assert_allclose(g.transform_points(Ti, g.transform_points(T, pts)), pts, atol=TRANS_TOL_M * 100)


@SETTINGS
@given(pose, pose)
def test_composition_conventions(T_a_b, T_b_c):
    p_c = np.array([[1.0, -2.0, 0.5]])
    T_a_c = T_a_b @ T_b_c
    np.testing.assert_allclose(g.transform_points(T_a_c, p_c),
                               g.transform_points(T_a_b, g.transform_points(T_b_c, p_c)), atol=TRANS_TOL_M * 100)
    np.testing.assert_allclose(g.inv_pose(T_a_c), g.inv_pose(T_b_c) @ g.inv_pose(T_a_b), atol=ROT_TOL)


@SETTINGS
@given(st.lists(pose, min_size=2, max_size=4))
def test_batched_helpers_match_one_by_one(poses):
    Ts = np.stack(poses)
    np.testing.assert_allclose(g.inv_pose(Ts), np.stack([g.inv_pose(T) for T in poses]), atol=ROT_TOL)
    xyz, q = g.pose_to_xyz_quat(Ts)
    np.testing.assert_allclose(g.pose_from_xyz_quat(xyz, q), Ts, atol=ROT_TOL)
    pts = np.ones((len(poses), 3))
    np.testing.assert_allclose(g.transform_points(Ts, pts),
                               np.stack([g.transform_points(T, p[None])[0] for T, p in zip(poses, pts)]), atol=1e-9)


@SETTINGS
@given(vec3)
def test_skew_is_the_cross_product(v):
    w = np.array([0.3, -1.2, 2.0])
    np.testing.assert_allclose(g.skew(v) @ w, np.cross(v, w), atol=1e-12)
    np.testing.assert_allclose(g.skew(v), -g.skew(v).T, atol=0)


@SETTINGS
@given(st.floats(-np.pi + 1e-6, np.pi - 1e-6), finite, finite)
def test_se2_embedding_and_projection(theta, tx, ty):
    T3 = g.make_pose(g.so3_exp(np.array([0.0, 0.0, theta])), np.array([tx, ty, 0.0]))
    np.testing.assert_allclose(g.yaw_of(T3[:3, :3]), theta, atol=ROT_TOL)
    np.testing.assert_allclose(g.project_to_se2(T3), T3, atol=ROT_TOL)
    # projecting a tilted pose keeps x, y, yaw and drops the rest
    tilted = T3 @ g.make_pose(g.so3_exp(np.array([0.1, -0.05, 0.0])), np.array([0.0, 0.0, 2.0]))
    P = g.project_to_se2(tilted)
    assert P[2, 3] == 0.0
    np.testing.assert_allclose(P[:2, 3], tilted[:2, 3], atol=TRANS_TOL_M)
    np.testing.assert_allclose(g.yaw_of(P[:3, :3]), g.yaw_of(tilted[:3, :3]), atol=ROT_TOL)


@pytest.mark.parametrize("angle", [0.0, 1e-12, 1e-9, 1e-7, 1e-4])
def test_tiny_angles(angle):
    phi = np.array([1.0, 2.0, -2.0]) / 3.0 * angle
    np.testing.assert_allclose(g.so3_log(g.so3_exp(phi)), phi, atol=1e-15)


@pytest.mark.parametrize("eps", [1e-3, 1e-6, 0.0])
def test_near_pi_angles(eps):
    axis = np.array([0.0, 0.6, 0.8])
    phi = (np.pi - eps) * axis
    back = g.so3_log(g.so3_exp(phi))
    # at exactly pi the sign of the axis is arbitrary; the rotation must be the same either way
    np.testing.assert_allclose(g.so3_exp(back), g.so3_exp(phi), atol=ROT_TOL)
    np.testing.assert_allclose(np.linalg.norm(back), np.pi - eps, atol=NEAR_PI_TOL_RAD)


def test_interpolate_poses_endpoints_midpoint_and_clamping():
    T0 = g.make_pose(np.eye(3), np.zeros(3))
    T1 = g.make_pose(g.so3_exp(np.array([0.0, 0.0, 1.0])), np.array([2.0, 0.0, 0.0]))
    stamps = np.array([0, 1_000_000_000], dtype=np.int64)
    q = np.array([-5, 0, 500_000_000, 1_000_000_000, 2_000_000_000], dtype=np.int64)
    out = g.interpolate_poses(stamps, np.stack([T0, T1]), q)
    np.testing.assert_allclose(out[0], T0, atol=ROT_TOL)
    np.testing.assert_allclose(out[1], T0, atol=ROT_TOL)
    np.testing.assert_allclose(out[2][:3, 3], [1.0, 0.0, 0.0], atol=TRANS_TOL_M)
    np.testing.assert_allclose(g.so3_log(out[2][:3, :3]), [0.0, 0.0, 0.5], atol=ROT_TOL)
    np.testing.assert_allclose(out[3], T1, atol=ROT_TOL)
    np.testing.assert_allclose(out[4], T1, atol=ROT_TOL)
    single = g.interpolate_poses(stamps[:1], T1[None], q)
    assert single.shape == (5, 4, 4) and np.allclose(single, T1)


def test_interpolate_poses_over_a_repeated_stamp_is_finite():
    """Two knots at the same instant (a zero-length span): the first pose at and before it, the second after,
    never NaN (and no RuntimeWarning)."""
    T0 = g.make_pose(np.eye(3), np.zeros(3))
    T1 = g.make_pose(g.so3_exp(np.array([0.0, 0.0, 1.0])), np.array([2.0, 0.0, 0.0]))
    stamps = np.array([10, 10], dtype=np.int64)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        out = g.interpolate_poses(stamps, np.stack([T0, T1]), np.array([5, 10, 11], dtype=np.int64))
    np.testing.assert_allclose(out[0], T0, atol=ROT_TOL)
    np.testing.assert_allclose(out[1], T0, atol=ROT_TOL)
    np.testing.assert_allclose(out[2], T1, atol=ROT_TOL)
