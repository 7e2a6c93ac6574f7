"""``untouched``: np.allclose(measured, guess, rtol=0, atol=1e-12), which it replaces, on the cases that matter."""

import numpy as np
import pytest

from lio_cli.core.odometry.pose_checks import untouched


@pytest.mark.parametrize("offset", [0.0, 1e-13, 1e-12, 1.5e-12, 1e-6, np.nan, np.inf])
def test_untouched_is_allclose_at_1e_12(offset):
    guess = np.eye(4)
    guess[:3, 3] = [1.0, -2.0, 0.5]
    for entry in [(0, 3), (2, 1), (1, 1)]:
        measured = guess.copy()
        measured[entry] += offset
        assert untouched(measured, guess) == np.allclose(measured, guess, rtol=0.0, atol=1e-12)


def _jump_by_numpy(measured, guess, max_m, max_rad):
    from lio_cli.geometry import inv_pose

    jump = inv_pose(guess) @ measured
    angle = np.arccos(np.clip((np.trace(jump[:3, :3]) - 1.0) / 2.0, -1.0, 1.0))
    return bool(np.linalg.norm(jump[:3, 3]) > max_m or angle > max_rad)


def test_exceeds_jump_is_the_translation_and_angle_of_the_relative_pose():
    from lio_cli.core.odometry.pose_checks import exceeds_jump
    from lio_cli.geometry import make_pose, so3_exp

    rng = np.random.default_rng(11)
    guess = make_pose(so3_exp(np.array([0.3, -1.2, 2.0])), np.array([5.0, -3.0, 1.0]))
    outcomes = set()
    for _ in range(500):
        step = make_pose(so3_exp(rng.normal(0.0, 0.25, 3)), rng.normal(0.0, 0.7, 3))
        measured = guess @ step
        got = exceeds_jump(measured, guess, 1.0, 0.35)
        assert got == _jump_by_numpy(measured, guess, 1.0, 0.35)
        outcomes.add(got)
    assert outcomes == {True, False}
    # 0.9 m along the guess's own x, turned 0.3 rad: within; 1.1 m or 0.4 rad: beyond
    for t, a, want in ((0.9, 0.3, False), (1.1, 0.0, True), (0.0, 0.4, True)):
        step = make_pose(so3_exp(np.array([0.0, 0.0, a])), np.array([t, 0.0, 0.0]))
        assert exceeds_jump(guess @ step, guess, 1.0, 0.35) is want
