"""The up direction's re-anchoring for the wheel-scale check (core/fuse/tilt_track.py)."""

from __future__ import annotations

import numpy as np

from lio_cli.core.fuse.tilt_track import SEGMENT_S, segment_starts, walk_variance


def test_a_log_is_split_into_whole_stretches_and_a_short_one_is_left_whole():
    t = np.arange(0.0, 45.0, 0.005)
    assert segment_starts(t).tolist() == [0]  # under two stretches: anchored at its first second, as ever
    t = np.arange(0.0, 5 * SEGMENT_S + 10.0, 0.005)
    starts = segment_starts(t)
    assert len(starts) == 5 and starts[0] == 0
    assert np.allclose(np.diff(t[starts]), (t[-1] - t[0]) / 5, atol=0.005)


def test_the_walk_restarts_at_each_anchor():
    spans = np.array([[1.0, 2.0], [3.0, 4.0], [31.0, 32.0], [33.0, 34.0]])
    K = walk_variance(spans, np.array([0.0, 30.0]))
    one = walk_variance(spans[:2], np.array([0.0]))
    assert np.allclose(K[:2, :2], one) and np.allclose(K[2:, 2:], one)  # 30 s on: the same walk again
    assert not K[:2, 2:].any() and not K[2:, :2].any()
    # one anchor: E[W(s)W(u)] = min(s, u) integrated; [1,2] with itself a h^2 + h^3/3 = 1 + 1/3
    assert one[0, 0] == np.float64(1.0 + 1.0 / 3.0) and one[0, 1] == 1.5
