"""The evaluation math on cases small enough to check by hand (no evo needed: values computed here)."""

from __future__ import annotations

import math

import numpy as np
import pytest

from lio_cli.errors import InputError
from lio_cli.evaluation import (
    EvalOptions,
    Trajectory,
    align,
    ape_errors,
    associate,
    evaluate,
    kitti_segment_errors,
    match_nearest,
    rpe_errors,
    rpe_pairs,
    statistics,
    umeyama,
)
from lio_cli.geometry import inv_pose, make_pose, so3_exp

EXACT = 1e-12  # closed-form cases: only float rounding
RECOVER = 1e-9  # Umeyama / Sim(3) recovery through an SVD
MS = 1_000_000
S = 1_000_000_000


def _rz(deg: float) -> np.ndarray:
    return so3_exp(np.array([0.0, 0.0, np.deg2rad(deg)]))


def _traj(stamps_ns, poses, name="t") -> Trajectory:
    return Trajectory(np.asarray(stamps_ns, dtype=np.int64), np.asarray(poses, dtype=np.float64), name)


def _three_pose_case():
    """Reference along x; estimate off by 0.3 m in y at pose 1 and 0.4 m in z plus 90 deg yaw at pose 2."""
    ref = np.stack([make_pose(t=[0, 0, 0]), make_pose(t=[1, 0, 0]), make_pose(t=[2, 0, 0])])
    est = np.stack([make_pose(t=[0, 0, 0]), make_pose(t=[1, 0.3, 0]), make_pose(_rz(90), [2, 0, 0.4])])
    return ref, est


# ---------------------------------------------------------------------------------------------- statistics


def test_statistics_match_their_definitions():
    s = statistics(np.array([1.0, 2.0, 3.0, 4.0]))
    assert s["rmse"] == pytest.approx(math.sqrt(30.0 / 4.0), rel=EXACT)
    assert s["mean"] == 2.5 and s["median"] == 2.5 and s["min"] == 1.0 and s["max"] == 4.0
    assert s["std"] == pytest.approx(math.sqrt(1.25), rel=EXACT)  # population std, as evo (np.std)
    assert s["sse"] == 30.0


# ---------------------------------------------------------------------------------------------- APE / RPE


def test_ape_three_pose_case_by_hand():
    ref, est = _three_pose_case()
    e = ape_errors(ref, est)
    np.testing.assert_allclose(e["trans"], [0.0, 0.3, 0.4], atol=EXACT)
    np.testing.assert_allclose(e["rot"], [0.0, 0.0, 90.0], atol=EXACT)
    np.testing.assert_allclose(e["rot_rad"], [0.0, 0.0, np.pi / 2], atol=EXACT)
    # E2 = est2^-1 ref2 = [Rz(-90) | (0,0,-0.4)]: |R - I|_F^2 = 2 (3 - trace R) = 4, plus 0.4^2
    np.testing.assert_allclose(e["full"], [0.0, 0.3, math.sqrt(4.16)], atol=EXACT)
    s = statistics(e["trans"])
    assert s["rmse"] == pytest.approx(math.sqrt(0.25 / 3.0), rel=EXACT)
    assert s["sse"] == pytest.approx(0.25, rel=EXACT)
    assert s["median"] == pytest.approx(0.3, rel=EXACT)


def test_rpe_three_pose_case_by_hand():
    ref, est = _three_pose_case()
    pairs = rpe_pairs(est, np.arange(3) * S, 1, "frames")
    np.testing.assert_array_equal(pairs, [[0, 1], [1, 2]])
    e = rpe_errors(ref, est, pairs)
    # pair (0,1): Q=[I|(1,0,0)], P=[I|(1,0.3,0)] -> E=[I|(0,0.3,0)]
    # pair (1,2): Q=[I|(1,0,0)], P=[Rz90|(1,-0.3,0.4)] -> E=[Rz90|(0,-0.3,0.4)]
    np.testing.assert_allclose(e["trans"], [0.3, 0.5], atol=EXACT)
    np.testing.assert_allclose(e["rot"], [0.0, 90.0], atol=EXACT)
    np.testing.assert_allclose(e["full"], [0.3, math.sqrt(4.0 + 0.25)], atol=EXACT)


def test_rotation_angle_near_pi_and_tiny():
    ref = np.stack([np.eye(4), np.eye(4)])
    est = np.stack([make_pose(_rz(179.999)), make_pose(so3_exp(np.array([1e-9, 0.0, 0.0])))])
    e = ape_errors(ref, est)
    np.testing.assert_allclose(e["rot"], [179.999, np.rad2deg(1e-9)], rtol=1e-9)


# ---------------------------------------------------------------------------------------------- pairs


def test_rpe_pairs_frames_consecutive_and_all():
    poses = np.repeat(np.eye(4)[None], 7, axis=0)
    np.testing.assert_array_equal(rpe_pairs(poses, np.arange(7), 3, "frames"), [[0, 3], [3, 6]])
    np.testing.assert_array_equal(rpe_pairs(poses, np.arange(7), 5, "frames", all_pairs=True), [[0, 5], [1, 6]])


def test_rpe_pairs_metres_seconds_degrees():
    n = 10
    line = np.stack([make_pose(_rz(10.0 * k), [float(k), 0.0, 0.0]) for k in range(n)])  # 1 m and 10 deg per step
    stamps = np.arange(n) * 500 * MS  # 0.5 s per step
    # accumulated path 1, 2, 3 >= 2.5 closes a window at 3 poses
    np.testing.assert_array_equal(rpe_pairs(line, stamps, 2.5, "m"), [[0, 3], [3, 6], [6, 9]])
    np.testing.assert_array_equal(rpe_pairs(line, stamps, 1.0, "s"), [[0, 2], [2, 4], [4, 6], [6, 8]])
    np.testing.assert_array_equal(rpe_pairs(line, stamps, 25.0, "deg"), [[0, 3], [3, 6], [6, 9]])
    np.testing.assert_array_equal(rpe_pairs(line, stamps, np.deg2rad(45.0), "rad"), [[0, 5]])
    all_m = rpe_pairs(line, stamps, 2.0, "m", all_pairs=True, rel_tol=0.1)
    np.testing.assert_array_equal(all_m, [[i, i + 2] for i in range(n - 2)])
    all_deg = rpe_pairs(line, stamps, 30.0, "deg", all_pairs=True, rel_tol=0.1)
    np.testing.assert_array_equal(all_deg, [[i, i + 3] for i in range(n - 3)])


def test_rpe_pairs_none_found_is_bad_input():
    poses = np.repeat(np.eye(4)[None], 3, axis=0)
    with pytest.raises(InputError, match="found no pose pairs among 3 poses; lower --delta"):
        rpe_pairs(poses, np.arange(3), 5, "frames")


# ---------------------------------------------------------------------------------------------- alignment


def test_umeyama_recovers_known_sim3_and_se3():
    rng = np.random.default_rng(3)
    src = rng.normal(size=(50, 3)) * 5.0
    R = so3_exp(np.array([0.3, -1.1, 2.0]))
    t = np.array([4.0, -2.0, 0.5])
    dst = 2.5 * src @ R.T + t
    R_hat, t_hat, s_hat = umeyama(src, dst, with_scale=True)
    np.testing.assert_allclose(R_hat, R, atol=RECOVER)
    np.testing.assert_allclose(t_hat, t, atol=RECOVER)
    assert s_hat == pytest.approx(2.5, rel=RECOVER)
    R_hat, t_hat, s_hat = umeyama(src, src @ R.T + t, with_scale=False)
    np.testing.assert_allclose(R_hat, R, atol=RECOVER)
    np.testing.assert_allclose(t_hat, t, atol=RECOVER)
    assert s_hat == 1.0


def test_umeyama_returns_a_rotation_for_mirrored_points():
    rng = np.random.default_rng(5)
    src = rng.normal(size=(20, 3))
    R_hat, _, _ = umeyama(src, src * np.array([1.0, 1.0, -1.0]), with_scale=False)
    assert np.linalg.det(R_hat) == pytest.approx(1.0, abs=RECOVER)


def test_umeyama_degenerate_line_is_bad_input():
    line = np.stack([np.arange(5.0), np.zeros(5), np.zeros(5)], axis=1)
    with pytest.raises(InputError, match="degenerate"):
        umeyama(line, line, with_scale=False)


def _smooth(n: int = 60, seed: int = 11) -> np.ndarray:
    rng = np.random.default_rng(seed)
    t = np.linspace(0.0, 6.0, n)
    poses = np.repeat(np.eye(4)[None], n, axis=0)
    poses[:, :3, 3] = np.stack([np.cos(t) * 5, np.sin(t) * 3, 0.2 * t], axis=1) + rng.normal(0, 0.01, (n, 3))
    poses[:, :3, :3] = so3_exp(np.stack([0.1 * np.sin(t), 0.1 * np.cos(t), t], axis=1))
    return poses


def _sim3_inverse_applied(ref: np.ndarray, R, t, s) -> np.ndarray:
    """Estimate such that aligning it with (R, t, s) gives back ``ref`` exactly."""
    est = ref.copy()
    est[:, :3, :3] = np.einsum("ji,njk->nik", R, ref[:, :3, :3])
    est[:, :3, 3] = ((ref[:, :3, 3] - t) @ R) / s
    return est


def test_alignment_modes_recover_what_was_applied():
    ref = _smooth()
    R, t = so3_exp(np.array([0.2, 0.4, -0.9])), np.array([1.0, 2.0, 3.0])
    est = _sim3_inverse_applied(ref, R, t, 0.8)
    al = align(ref, est, "sim3")
    assert al.scale == pytest.approx(0.8, rel=RECOVER)
    np.testing.assert_allclose(al.apply(est), ref, atol=RECOVER)
    np.testing.assert_allclose(ape_errors(ref, al.apply(est))["trans"], 0.0, atol=RECOVER)
    # SE(3) cannot absorb the scale: error stays
    assert ape_errors(ref, align(ref, est, "se3").apply(est))["trans"].max() > 0.1
    # scale only: positions scaled, rotations untouched
    est_scaled = ref.copy()
    est_scaled[:, :3, 3] /= 1.25
    al = align(ref, est_scaled, "scale")
    assert al.scale == pytest.approx(1.25, rel=RECOVER)
    np.testing.assert_allclose(al.apply(est_scaled), ref, atol=RECOVER)


def test_origin_alignment_makes_first_poses_coincide():
    ref = _smooth()
    T = make_pose(so3_exp(np.array([0.0, 0.3, 1.0])), [5.0, -4.0, 1.0])
    est = np.einsum("ij,njk->nik", inv_pose(T), ref)
    al = align(ref, est, "origin")
    np.testing.assert_allclose(al.apply(est), ref, atol=EXACT * 100)


def test_alignment_on_first_n_poses_only():
    ref = _smooth()
    R, t = so3_exp(np.array([0.0, 0.0, 0.5])), np.array([2.0, 0.0, 0.0])
    est = _sim3_inverse_applied(ref, R, t, 1.0)
    est[20:, :3, 3] += np.array([0.0, 0.0, 1.0])  # the tail is off by 1 m
    aligned = align(ref, est, "se3", n_align=20).apply(est)
    e = ape_errors(ref, aligned)["trans"]
    np.testing.assert_allclose(e[:20], 0.0, atol=RECOVER)
    np.testing.assert_allclose(e[20:], 1.0, atol=RECOVER)


# ---------------------------------------------------------------------------------------------- association


def test_nearest_matching_ties_bounds_and_range():
    ref = np.array([0, 10, 20, 30], dtype=np.int64) * MS
    est = np.array([-10, 5, 14, 26, 40, 41], dtype=np.int64) * MS
    i_est, i_ref = match_nearest(est, ref, 10 * MS)
    # -10 -> 0 (10 ms, inclusive); 5 is a tie between 0 and 10 -> earlier; 14 -> 10; 26 -> 30; 40 -> 30; 41 out
    np.testing.assert_array_equal(i_est, [0, 1, 2, 3, 4])
    np.testing.assert_array_equal(i_ref, [0, 0, 1, 3, 3])


def test_associate_drives_from_the_sparser_trajectory_with_offset():
    ref = _traj(np.arange(10) * 10 * MS, np.repeat(np.eye(4)[None], 10, axis=0), "ref")
    est = _traj(np.array([5 * S + 21 * MS, 5 * S + 59 * MS]), np.repeat(np.eye(4)[None], 2, axis=0), "est")
    a = associate(ref, est, 10 * MS, -5 * S)
    np.testing.assert_array_equal(a.ref_indices, [2, 6])
    np.testing.assert_array_equal(a.est_indices, [0, 1])
    np.testing.assert_array_equal(a.ref.stamps_ns, [20 * MS, 60 * MS])


def test_interpolation_resamples_the_denser_reference():
    ref = _traj([0, S, 2 * S], [make_pose(t=[0, 0, 0]), make_pose(_rz(90), [10, 0, 0]), make_pose(_rz(90), [20, 0, 0])])
    est = _traj([S // 4], [np.eye(4)])
    # as in evo, a pose must still have a neighbour within max_diff; it is then interpolated at its exact stamp
    a = associate(ref, est, 300 * MS, 0, "interpolate")
    assert a.interpolated == "reference"
    np.testing.assert_allclose(a.ref.poses[0][:3, 3], [2.5, 0, 0], atol=EXACT)
    np.testing.assert_allclose(a.ref.poses[0][:3, :3], _rz(22.5), atol=EXACT)


def test_no_match_explains_unit_mixup_and_offset():
    ref = _traj(np.arange(1, 101) * S, np.repeat(np.eye(4)[None], 100, axis=0), "gt.tum")
    est_ms = _traj(np.arange(1, 101) * S * 1000, np.repeat(np.eye(4)[None], 100, axis=0), "est.tum")
    with pytest.raises(InputError, match=r"est.tum's stamps look like ms read as seconds; pass --est-stamp-unit ms"):
        associate(ref, est_ms)
    est_late = _traj(np.arange(1, 101) * S + 50 * S + 500 * S, np.repeat(np.eye(4)[None], 100, axis=0), "est.tum")
    with pytest.raises(InputError, match=r"do not overlap; .* pass --t-offset -550$"):
        associate(ref, est_late)
    est_off = _traj(np.arange(1, 101) * S + 300 * MS, np.repeat(np.eye(4)[None], 100, axis=0), "est.tum")
    with pytest.raises(InputError, match=r"closest stamps are 0.3 s apart; raise --t-max-diff"):
        associate(ref, est_off)


# ---------------------------------------------------------------------------------------------- KITTI, drift


def test_kitti_segments_on_a_straight_line_with_scale_error():
    n = 1001  # 1000 m at 1 m per pose
    ref = np.repeat(np.eye(4)[None], n, axis=0)
    ref[:, 0, 3] = np.arange(n, dtype=np.float64)
    est = ref.copy()
    est[:, 0, 3] *= 1.02
    k = kitti_segment_errors(ref, est)
    # a segment from i ends at the first j with dist > dist[i] + L, i.e. j = i + L + 1: error 0.02 (L + 1) / L;
    # starts every 10th pose while j <= 1000
    errs, total = [], 0
    for L in range(100, 900, 100):
        count = len(range(0, 1000 - L, 10))
        errs += [0.02 * (L + 1) / L] * count
        total += count
        assert k["per_length"][f"{L}"]["segments"] == count
    assert k["segments"] == total
    assert k["trans_pct"] == pytest.approx(np.mean(errs) * 100.0, rel=EXACT)
    assert k["rot_deg_per_100m"] == pytest.approx(0.0, abs=EXACT)


def test_kitti_segments_absent_on_short_runs():
    ref = np.repeat(np.eye(4)[None], 20, axis=0)
    ref[:, 0, 3] = np.arange(20.0)
    k = kitti_segment_errors(ref, ref)
    assert k["segments"] == 0 and k["trans_pct"] is None and "shorter than the shortest segment" in k["note"]


def test_evaluate_drift_and_final_error():
    n = 11
    ref = np.repeat(np.eye(4)[None], n, axis=0)
    ref[:, 0, 3] = np.arange(n) * 2.0  # 20 m
    est = ref.copy()
    est[:, 1, 3] = np.linspace(0.0, 0.5, n)  # ends 0.5 m to the side
    r = evaluate(_traj(np.arange(n) * S, ref, "gt"), _traj(np.arange(n) * S, est, "est"), EvalOptions(align="none"))
    assert r.drift["final_error_m"] == pytest.approx(0.5, rel=EXACT)
    assert r.drift["drift_pct"] == pytest.approx(2.5, rel=EXACT)
    assert r.flat_metrics()["ape_rmse"] == pytest.approx(math.sqrt(np.mean(np.linspace(0, 0.5, n) ** 2)), rel=EXACT)


def test_evaluate_needs_three_matches_for_umeyama():
    ref = _traj([0, S], np.repeat(np.eye(4)[None], 2, axis=0), "gt")
    with pytest.raises(InputError, match=r"only 2 matching poses between gt and est \(need at least 3\)"):
        evaluate(ref, _traj([0, S], np.repeat(np.eye(4)[None], 2, axis=0), "est"))


def test_no_match_of_epoch_against_relative_stamps_is_no_unit_mixup():
    """KITTI times.txt (from 0) against an epoch reference, 6 s each: the ends' ratio (6 / 1.7e9) is that of ns
    read as seconds, but the spans are equal, so it is no unit mix-up (it said "gt.tum's stamps look like ns read
    as seconds"); the hint is the offset, to the nanosecond (it said --t-offset 1.7e+09, 0.1 s short)."""
    poses = np.repeat(np.eye(4)[None], 61, axis=0)
    ref = _traj(1_700_000_000 * S + 100 * MS + np.arange(61) * 100 * MS, poses, "gt.tum")
    est = _traj(np.arange(61) * 100 * MS, poses, "k.txt")
    with pytest.raises(InputError) as err:
        associate(ref, est)
    assert str(err.value).endswith(": the time ranges do not overlap; if the clocks differ by a constant, "
                                   "pass --t-offset 1700000000.1")
