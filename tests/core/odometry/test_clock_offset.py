"""The online IMU clock-offset tracker against synthetic handheld motion with a known offset.

The LiDAR poses here are noisy but not primed by the IMU, so a round measures the whole offset that is left
(in ``lio odom`` each round finds about half of it: see ``clock_offset``)."""

from types import SimpleNamespace

import numpy as np
import pytest

import lio_cli.core.odometry.clock_offset as clock_offset

from lio_cli.core.odometry.clock_offset import ClockOffsetTracker
from lio_cli.simulation.calibration_inputs import calibration_inputs

OFFSET_S = -0.012  # t_lidar = t_imu_stamp + offset: the IMU stamps 12 ms late


@pytest.fixture(scope="module")
def walk():
    return calibration_inputs("handheld", 8.0, seed=3, imu_time_offset_s=OFFSET_S)


def _run(walk, seconds: float) -> ClockOffsetTracker:
    """Feed poses and IMU in time order as the odometry does, shifting later IMU stamps by what it applies."""
    tracker, shift_ns, j = ClockOffsetTracker(), 0, 0
    imu = walk.imu
    stamps = walk.lidar_stamps_ns[walk.lidar_stamps_ns <= walk.lidar_stamps_ns[0] + int(seconds * 1e9)]
    for k, t in enumerate(stamps):
        i = int(np.searchsorted(imu.stamps_ns + shift_ns, t, side="right"))
        tracker.add_imu(imu.stamps_ns[j:i] + shift_ns, imu.gyro_radps[j:i])
        j = i
        tracker.add_pose(int(t), walk.T_world_lidar[k])
        shift_ns += tracker.propose(np.zeros(3), k)
    tracker.close(np.zeros(3), len(stamps))
    return tracker


def test_rounds_apply_the_offset_until_one_finds_nothing_left(walk):
    """2.5 s rounds: the first applies most of it, the next what it missed, the third finds the clocks agree
    to under a millisecond, sharply, and ends the rounds (no closing round then)."""
    tracker = _run(walk, 8.0)
    assert tracker.applied_s == pytest.approx(OFFSET_S, abs=5e-4)
    assert [e["applied"] for e in tracker.estimates] == [True, True, False]
    last = tracker.estimates[-1]
    assert abs(last["offset_s"]) < 1e-3 and last["sigma_s"] <= 1e-3 and "final" not in last and tracker.done
    assert tracker.estimate_s == pytest.approx(OFFSET_S, abs=5e-4)


def test_the_closing_round_measures_a_window_too_short_for_an_online_round(walk):
    tracker = _run(walk, clock_offset.WINDOW_S - 0.1)  # under a round's 2.5 s, over the closing one's 2.3 s
    assert tracker.applied_s == 0.0
    final = tracker.estimates[-1]
    assert final["final"] is True and final["applied"] is False and len(tracker.estimates) == 1
    assert final["sigma_s"] < 0.002  # sharp enough to be taken, and the truth within 3 sigma of it
    assert tracker.residual_s == pytest.approx(OFFSET_S, abs=3 * final["sigma_s"])
    assert tracker.estimate_s == tracker.residual_s


def test_a_window_with_doubted_scans_applies_an_offset_measured_to_5_ms(walk, monkeypatch):
    """An offset 4.5 sigma from zero at a 4 ms sigma: not applied from an ordinary window (2 ms at most), applied
    from one holding a doubted scan's pose (the IMU state's disagreement is the evidence; 5 ms at most)."""
    measured = SimpleNamespace(imu_time_offset_s=0.018, sigma_s=0.004)
    monkeypatch.setattr(clock_offset, "estimate_time_offset", lambda *a, **kw: measured)
    for doubted, applied in ((False, 0.0), (True, 0.018)):
        tracker = ClockOffsetTracker()
        tracker.add_imu(walk.imu.stamps_ns, walk.imu.gyro_radps)
        stamps = walk.lidar_stamps_ns[walk.lidar_stamps_ns <= walk.lidar_stamps_ns[0] + 3_000_000_000]
        proposed = []
        for k, t in enumerate(stamps):
            tracker.add_pose(int(t), walk.T_world_lidar[k], doubted=doubted and k == 5)
            proposed.append(tracker.propose(np.zeros(3), k))
        assert tracker.applied_s == applied and sum(proposed) == round(applied * 1e9)
        assert tracker.estimates[0]["applied"] is doubted and not tracker.doubted  # the next window starts clean


def test_too_short_a_window_measures_nothing(walk):
    tracker = _run(walk, 2.1)
    assert tracker.estimates == [] and tracker.estimate_s == 0.0


@pytest.mark.parametrize("offset_ms, sigma_ms, applied, ends", [
    (5.5, 1.5, True, False),  # 3.5 sigma and a millisecond: applied
    (4.64, 1.535, False, False),  # 3.0 sigma: not (a 2.5 s round of a walk without an offset measured this)
    (2.7, 0.75, True, False),
    (0.9, 0.2, False, True),  # under a millisecond, sharply: the clocks agree; kept as the residual, not applied
    (2.5, 2.1, False, False),  # too loose a round
    (2.4, 0.85, False, False),  # under 3 sigma, not agreement either: the rounds go on (they ended on a walk 15 ms off)
])
def test_what_a_round_applies(monkeypatch, walk, offset_ms, sigma_ms, applied, ends):
    est = SimpleNamespace(imu_time_offset_s=offset_ms * 1e-3, sigma_s=sigma_ms * 1e-3)
    monkeypatch.setattr(clock_offset, "estimate_time_offset", lambda *a, **k: est)
    tracker = _run(walk, 2 * clock_offset.WINDOW_S + 0.1)  # two rounds, unless the first ends them
    assert tracker.estimates[0]["applied"] is applied
    assert len(tracker.estimates) == (1 if ends else 2)
    assert tracker.applied_s == pytest.approx(2 * offset_ms * 1e-3 if applied else 0.0)
    assert tracker.residual_s == pytest.approx(offset_ms * 1e-3 if offset_ms == 0.9 else 0.0)
