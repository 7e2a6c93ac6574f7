"""A growing track's rows kept in blocks: what a list of them gave, across block boundaries."""

from __future__ import annotations

import numpy as np
import pytest

from lio_cli.model.trajectory import Rows


@pytest.mark.parametrize("block", [1, 3, 1024])
def test_rows_behave_as_the_list_they_replace(block):
    rng = np.random.default_rng(0)
    poses, stamps = Rows((4, 4), block=block), Rows((), np.int64, block=block)
    want_p, want_s = [], []
    for k in range(10):
        p = rng.normal(size=(4, 4))
        poses.append(p), want_p.append(p.copy())
        stamps.append(10**18 + k), want_s.append(10**18 + k)
    p[:] = 0  # the row was copied in
    assert len(poses) == 10 and bool(poses) and not Rows()
    assert all(np.array_equal(a, b) for a, b in zip(poses, want_p)) and len(list(poses)) == 10
    assert np.array_equal(poses[-1], want_p[-1]) and np.array_equal(poses[4], want_p[4])
    assert stamps[3] == want_s[3] and type(stamps[3]) is int and list(stamps) == want_s
    assert np.array_equal(np.asarray(poses), np.stack(want_p)) and np.asarray(stamps).dtype == np.int64
    assert np.array_equal(np.asarray(stamps), want_s) and np.array_equal(poses[2:5], np.stack(want_p[2:5]))
    assert np.array_equal(stamps[-3:], want_s[-3:])
    with pytest.raises(IndexError):
        poses[10]
    with pytest.raises(IndexError):
        stamps[-11]
    del poses[7:], stamps[7:]  # a restart: the rows from 7 on dropped, then new ones
    del want_p[7:], want_s[7:]
    for k in range(4):
        poses.append(np.full((4, 4), k)), want_p.append(np.full((4, 4), float(k)))
        stamps.append(-k), want_s.append(-k)
    assert np.array_equal(np.asarray(poses), np.stack(want_p)) and list(stamps) == want_s
    del poses[0:], stamps[-100:]
    assert len(poses) == 0 and len(stamps) == 0 and np.asarray(poses).shape == (0, 4, 4)
    poses.append(np.eye(4))
    assert np.array_equal(np.asarray(poses), np.eye(4)[None])
    with pytest.raises(TypeError):
        del poses[1:2]
