"""Time-offset estimation: a known shift recovered on simulated trajectories, ranges, failures, flat cases."""

from __future__ import annotations

import numpy as np
import pytest

from lio_cli.errors import InputError
from lio_cli.evaluation import EvalOptions, Trajectory, evaluate
from lio_cli.evaluation.offset import default_range_ns, estimate_offset
from lio_cli.geometry import make_pose, so3_exp

S = 1_000_000_000
SHIFT_S = 0.137
RECOVERY_TOL_NS = 1_000_000  # the target: within 1 ms
T0_NS = 1_000 * S


def _motion(t: np.ndarray) -> np.ndarray:
    """Poses of a smooth 3D path with turns and speed changes, at times t (s)."""
    pos = np.stack([20 * np.sin(0.05 * t), 12 * np.sin(0.1 * t) + 0.3 * t, 1.5 * np.sin(0.2 * t)], axis=1)
    rv = np.stack([0.2 * np.sin(0.3 * t), 0.15 * np.cos(0.25 * t), 0.4 * t], axis=1)
    P = np.repeat(np.eye(4)[None], len(t), axis=0)
    P[:, :3, :3] = so3_exp(rv)
    P[:, :3, 3] = pos
    return P


def _pair(seed: int, shift_s: float, est_clock_ns: int = 0, ref_hz: float = 100.0, est_n: int = 1200,
          duration_s: float = 60.0, noise_m: float = 0.005, tilt: bool = True, drift_m: float = 0.0,
          rot_noise_rad: float = 0.0005) -> tuple[Trajectory, Trajectory]:
    """Reference sampled regularly; estimate at random instants, in another world frame, with noise; its stamps
    read ``true time - shift`` on a clock ``est_clock_ns`` ahead, so the right offset is ``shift - clock``.
    ``tilt=False``: the two world frames differ by a yaw and a translation only (what posyaw can undo).
    ``drift_m``: a random walk of this step added to the estimate's positions, as odometry drifts."""
    rng = np.random.default_rng(seed)
    t_ref = np.arange(0.0, duration_s, 1.0 / ref_hz)
    t_est = np.sort(rng.uniform(0.5, duration_s - 0.5, est_n))
    T = make_pose(so3_exp(np.array([0.1, -0.2, 0.7]) if tilt else np.array([0.0, 0.0, 0.7])), np.array([3.0, -1.0, 0.5]))
    est = T @ _motion(t_est)
    est[:, :3, 3] += rng.normal(0, noise_m, (est_n, 3)) + np.cumsum(rng.normal(0, drift_m, (est_n, 3)), axis=0)
    est[:, :3, :3] = est[:, :3, :3] @ so3_exp(rng.normal(0, rot_noise_rad, (est_n, 3)))
    ref_ns = T0_NS + np.round(t_ref * 1e9).astype(np.int64)
    est_ns = T0_NS + est_clock_ns + np.round((t_est - shift_s) * 1e9).astype(np.int64)
    return Trajectory(ref_ns, _motion(t_ref), "ref"), Trajectory(est_ns, est, "est")


@pytest.mark.parametrize("seed", [0, 1])
def test_recovers_a_known_shift_within_a_millisecond(seed):
    ref, est = _pair(seed, SHIFT_S)
    f = estimate_offset(ref, est, 10_000_000, "se3")
    assert abs(f.offset_ns - round(SHIFT_S * 1e9)) < RECOVERY_TOL_NS
    assert f.rmse_m < 0.03 and f.note is None and f.best_matches == f.sampled
    assert f.range_ns == default_range_ns(ref, est)


def test_recovers_across_clocks_an_epoch_apart_and_with_a_sparse_reference():
    clock = -1_700_000_000 * S  # the estimate counts from boot, the reference from 1970
    ref, est = _pair(2, -2.5, est_clock_ns=clock)
    f = estimate_offset(ref, est, 10_000_000, "sim3")
    assert abs(f.offset_ns - (round(-2.5 * 1e9) - clock)) < RECOVERY_TOL_NS
    # a 5 Hz position-only reference (GPS-like) against a 50 Hz estimate: the estimate is the one interpolated
    ref, est = _pair(3, SHIFT_S, ref_hz=5.0, est_n=3000, tilt=False)
    ref.poses[:, :3, :3] = np.eye(3)
    f = estimate_offset(ref, est, 10_000_000, "posyaw")
    assert f.alignment == "posyaw"
    assert abs(f.offset_ns - round(SHIFT_S * 1e9)) < RECOVERY_TOL_NS


def test_drifting_positions_leave_the_offset_to_the_rotations():
    ref, est = _pair(7, SHIFT_S, est_n=4000, drift_m=0.007)  # ~0.4 m of drift, correlated with the motion
    f = estimate_offset(ref, est, 10_000_000, "se3")
    assert f.decided_by == "rotations" and set(f.by_term) == {"positions", "rotations"}
    assert abs(f.offset_ns - round(SHIFT_S * 1e9)) < RECOVERY_TOL_NS
    pos, rot = f.by_term["positions"], f.by_term["rotations"]
    assert rot["precision_s"] < pos["precision_s"] and f.precision_s == rot["precision_s"]
    # the precisions are honest: each term's own error stays within a few of its sigmas
    for term in (pos, rot):
        assert abs(term["offset_s"] - SHIFT_S) < 4 * term["precision_s"] + 1e-5
    # without orientations (GPS) only positions remain
    f = estimate_offset(ref, est, 10_000_000, "se3", rotations=False)
    assert f.decided_by == "positions" and set(f.by_term) == {"positions"} and f.rot_rmse_deg is None


@pytest.mark.parametrize("seed", [0, 4])
def test_the_precision_stays_honest_when_only_turns_of_the_rate_determine_the_offset(seed):
    # 200 s of a yaw at a steady 0.4 rad/s: a time shift looks like a world rotation except where the axis
    # tilts, noisy rotations (0.17 deg), drifting positions. The offset is known only to a few ms here, and the
    # precision must say so (a slope-spread estimate alone said ~1 ms with errors of 4-5 ms)
    ref, est = _pair(seed, SHIFT_S, est_n=6000, duration_s=200.0, noise_m=0.01, drift_m=0.002, rot_noise_rad=0.003)
    f = estimate_offset(ref, est, 10_000_000, "sim3")
    assert f.decided_by == "rotations"
    assert 1.5e-3 < f.precision_s < 4e-3
    assert abs(f.offset_s - SHIFT_S) < 3 * f.precision_s


def test_default_range_overlaps_by_half_the_shorter_span():
    ref = Trajectory(np.array([0, 10]) * S, np.repeat(np.eye(4)[None], 2, 0), "ref")
    est = Trajectory(np.array([100, 104]) * S, np.repeat(np.eye(4)[None], 2, 0), "est")
    # est shifted by d spans 100+d..104+d; overlap >= 2 s needs d >= -102 and d <= -92
    assert default_range_ns(ref, est) == (-102 * S, -92 * S)


def test_nothing_in_the_range_pairs_says_which_offsets_would():
    ref = Trajectory(np.arange(0, 11) * S, np.repeat(np.eye(4)[None], 11, 0), "ref")
    est = Trajectory(np.arange(100, 111) * S, np.repeat(np.eye(4)[None], 11, 0), "est")
    with pytest.raises(InputError) as err:
        estimate_offset(ref, est, 10_000_000, "se3", (-S, S))
    assert str(err.value) == (
        "--estimate-offset: no offset in -1..1 s pairs any stamp of est with one of ref within --t-max-diff 0.01 s; "
        "offsets in -110.01..-89.99 s overlap their time ranges (the midpoints meet at -100 s): widen --offset-range")


def test_a_standing_platform_gives_a_flagged_offset():
    stamps = T0_NS + np.arange(200) * 10_000_000
    still = np.repeat(make_pose(t=[1.0, 2.0, 0.0])[None], 200, axis=0)
    rng = np.random.default_rng(4)
    noisy = still.copy()
    noisy[:, :3, 3] += rng.normal(0, 0.001, (200, 3))
    f = estimate_offset(Trajectory(stamps, still, "ref"), Trajectory(stamps[::2], noisy[::2], "est"), 10_000_000, "none")
    assert f.note is not None and f.note.endswith("the motion barely determines it")


def test_evaluate_uses_the_estimated_offset():
    ref, est = _pair(5, SHIFT_S)
    plain = evaluate(ref, est, EvalOptions(method="interpolate"))
    found = evaluate(ref, est, EvalOptions(method="interpolate", estimate_offset=True))
    assert abs(found.offset_ns - round(SHIFT_S * 1e9)) < RECOVERY_TOL_NS
    assert found.flat_metrics()["t_offset_s"] == found.offset_ns / 1e9
    assert found.summary()["association"]["t_offset_s"] == found.offset_ns / 1e9
    assert found.summary()["time_offset"]["offset_s"] == found.offset.offset_s
    # 0.137 s at up to ~2.5 m/s is tens of cm of APE; with the offset only the 5 mm noise remains
    assert plain.stats["ape"]["trans"]["rmse"] > 0.1 and found.stats["ape"]["trans"]["rmse"] < 0.03
