"""Evaluating against (or of) a position-only trajectory: translation metrics only, computed as displacements."""

from __future__ import annotations

import numpy as np
import pytest

from lio_cli.errors import InputError
from lio_cli.evaluation import EvalOptions, Trajectory, evaluate
from lio_cli.geometry import make_pose, so3_exp

EXACT = 1e-12
S = 1_000_000_000


def _rz(deg: float) -> np.ndarray:
    return so3_exp(np.array([0.0, 0.0, np.deg2rad(deg)]))


def _case():
    stamps = np.array([10, 11, 12]) * S
    gps = np.stack([make_pose(t=[0, 0, 0]), make_pose(t=[1, 0, 0]), make_pose(t=[2, 0, 0])])  # positions only
    est = np.stack([make_pose(t=[0, 0, 0]), make_pose(_rz(90), [1, 0.3, 0]), make_pose(_rz(90), [2, 0, 0.4])])
    return Trajectory(stamps, gps, "gps"), Trajectory(stamps, est, "est")


def test_translation_only_by_hand():
    ref, est = _case()
    r = evaluate(ref, est, EvalOptions(align="none", translation_only=True))
    np.testing.assert_allclose(r.ape["trans"], [0.0, 0.3, 0.4], atol=EXACT)
    # RPE: world displacements (1, 0.3, 0) vs (1, 0, 0) and (1, -0.3, 0.4) vs (1, 0, 0)
    np.testing.assert_allclose(r.rpe["trans"], [0.3, 0.5], atol=EXACT)
    assert set(r.ape) == {"trans"} and set(r.rpe) == {"trans"}
    assert all(v is None for v in r.stats["ape"]["rot"].values())
    m = r.flat_metrics()
    assert m["ape_rot_rmse"] is None and m["rpe_full_max"] is None and m["kitti_rot_deg_per_100m"] is None
    assert m["rpe_trans_max"] == pytest.approx(0.5, abs=EXACT)
    assert r.summary()["translation_only"] is True
    # the same data with orientations taken at face value: pose 1's heading turns its displacement 90 deg
    full = evaluate(ref, est, EvalOptions(align="none"))
    assert full.rpe["trans"][1] > 1.0


def test_kitti_segments_of_a_position_only_reference_have_no_rotation():
    n = 1000  # 125 m straight at 0.125 m per pose (exact in binary), the estimate 1 % long
    stamps = np.arange(n) * (S // 10)
    ref = np.repeat(np.eye(4)[None], n, axis=0)
    ref[:, 0, 3] = 0.125 * np.arange(n)
    est = ref.copy()
    est[:, 0, 3] *= 1.01
    est[:, :3, :3] = _rz(30)  # a heading the GPS cannot contradict
    r = evaluate(Trajectory(stamps, ref, "gps"), Trajectory(stamps, est, "est"),
                 EvalOptions(align="none", translation_only=True))
    assert r.kitti["segments"] > 0 and r.kitti["rot_deg_per_100m"] is None
    # a segment ends at the first pose past L (the devkit's rule): 100.125 m, 1 % of it over L = 100 m
    assert r.kitti["per_length"]["100"]["trans_pct"] == pytest.approx(1.00125, rel=1e-12)
    assert all(v["rot_deg_per_100m"] is None for v in r.kitti["per_length"].values())


def test_origin_alignment_is_refused():
    ref, est = _case()
    with pytest.raises(InputError) as err:
        evaluate(ref, est, EvalOptions(align="origin", translation_only=True))
    assert str(err.value) == ("--align origin needs orientations, and gps or est has positions only (GPS); "
                              "use se3, sim3, scale, posyaw or none")
