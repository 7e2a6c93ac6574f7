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
