"""score(): what `odom --gt` and `fuse --gt` report against ground truth."""

import numpy as np

from lio_cli.evaluation.scoring import score
from lio_cli.model.trajectory import Trajectory


def _track(xy: np.ndarray, hz: float = 10.0) -> Trajectory:
    poses = np.repeat(np.eye(4)[None], len(xy), axis=0)
    poses[:, :2, 3] = xy
    stamps = (np.arange(len(xy)) * 1e9 / hz).astype(np.int64)
    return Trajectory(stamps, poses, name="t")


def _curve(n: int) -> np.ndarray:
    t = np.arange(n) / 10.0
    return np.stack([2.0 * t, 3.0 * np.sin(0.3 * t)], axis=1)  # 2 m/s along x, weaving in y


def test_rpe_over_10_m_on_a_long_path():
    ref = _track(_curve(300))  # 60 m in 30 s
    est = _track(_curve(300) + 0.01)
    s = score(ref, est)
    assert s.rpe_delta == "10 m"
    assert s.rpe_trans_rmse_m is not None and s.rpe_trans_rmse_m < 1e-6


def test_a_track_lost_early_falls_back_to_rpe_over_1_s():
    ref = _track(_curve(300))
    stuck = _curve(300)
    stuck[40:] = stuck[40]  # lost after 4 s (8 m): the estimate stops while the reference goes on
    s = score(ref, _track(stuck))
    assert s.rpe_delta == "1 s"
    assert s.ate_trans_rmse_m > 5.0  # the error is reported, not hidden
    assert s.rpe_trans_rmse_m is not None and s.rpe_trans_rmse_m > 0.5
