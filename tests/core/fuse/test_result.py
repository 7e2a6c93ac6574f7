"""What a run hands back: origin start, covariance layout, JSON-able summary."""

from __future__ import annotations

import json

import numpy as np

from lio_cli.core.fuse import COVARIANCE_LAYOUT, FuseOptions, fuse
from lio_cli.core.fuse.result import anchor_to_origin, pose_covariance_index
from lio_cli.core.fuse.state3d import DP, TH
from lio_cli.geometry import make_pose, so3_exp
from lio_cli.simulation.fusion_case import OdomNoise, simulate_case


def test_anchor_to_origin_shifts_positions_only():
    T = np.stack([make_pose(so3_exp(np.array([0, 0, 0.5])), np.array([1.0, 2.0, 3.0])),
                  make_pose(np.eye(3), np.array([2.0, 2.0, 3.0]))])
    out = anchor_to_origin(T)
    np.testing.assert_allclose(out[:, :3, 3], [[0, 0, 0], [1.0, 0, 0]])
    np.testing.assert_allclose(out[:, :3, :3], T[:, :3, :3])


def test_covariance_layout_is_position_then_rotation():
    P = np.arange(15 * 15, dtype=float).reshape(1, 15, 15)
    idx = pose_covariance_index(TH, DP)
    C = P[:, idx][:, :, idx]
    assert C.shape == (1, 6, 6) and COVARIANCE_LAYOUT[0] == "x_m" and COVARIANCE_LAYOUT[3] == "rot_x_rad"
    np.testing.assert_array_equal(C[0, 0, 0], P[0, 3, 3])
    np.testing.assert_array_equal(C[0, 3, 0], P[0, 0, 3])
    np.testing.assert_array_equal(C[0, 5, 5], P[0, 2, 2])


def test_summary_is_json_and_says_what_was_used():
    case = simulate_case("handheld", 3.0, seed=1, wheels=False, odom=OdomNoise())
    res = fuse(case.inputs, FuseOptions(estimator="ekf", rate_hz=20.0))
    s = json.loads(json.dumps(res.summary()))
    assert s["estimator"] == "ekf" and s["poses"] == len(res) == 61
    assert s["use"] == {"imu": ["accel", "gyro"], "odom": ["pose"]}
    assert s["sources"]["odom"]["updates"] == len(case.inputs.odom) - 1
    assert s["sources"]["odom"]["by_kind"] == {"odom": {"updates": len(case.inputs.odom) - 1, "outlier": 0}}
    assert s["sources"]["imu"]["predictions"] == len(case.inputs.imu)
    np.testing.assert_allclose(res.poses[0, :3, 3], 0.0)
    assert np.all(np.linalg.eigvalsh(res.covariances) > 0.0)


def test_without_covariance_nothing_is_kept_and_poses_are_the_same():
    case = simulate_case("planar", 3.0, seed=1)
    for est in ("ekf", "planar"):
        for smooth in (False, True):
            a = fuse(case.inputs, FuseOptions(estimator=est, smooth=smooth, rate_hz=10.0))
            b = fuse(case.inputs, FuseOptions(estimator=est, smooth=smooth, rate_hz=10.0, want_covariance=False))
            assert b.covariances is None and a.covariances.shape == (len(a), 6, 6)
            np.testing.assert_allclose(a.poses, b.poses, atol=1e-12)
