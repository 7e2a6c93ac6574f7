"""``plots.evaluate``: the PNGs of ``lio evaluate --plot`` from evaluation results."""

import numpy as np
import pytest

from lio_cli.errors import InputError
from lio_cli.evaluation import EvalOptions, evaluate
from lio_cli.geometry import make_pose, so3_exp
from lio_cli.model.trajectory import Trajectory
from lio_cli.plots.evaluate import GROUPS_PLOT, OFFSET_PLOT, PLOT_FILES, write_plots

NS = 1_000_000_000
PNG = b"\x89PNG\r\n\x1a\n"


def _circle(n=200, noise_m=0.0, seed=0):
    rng = np.random.default_rng(seed)
    a = np.linspace(0.0, 2 * np.pi, n)
    xyz = np.column_stack([5 * np.cos(a), 5 * np.sin(a), 0.1 * np.sin(3 * a)]) + rng.normal(0.0, noise_m, (n, 3))
    poses = np.stack([make_pose(so3_exp(np.array([0.0, 0.0, yaw])), p) for yaw, p in zip(a, xyz)])
    return np.arange(n, dtype=np.int64) * (NS // 10), poses


def test_write_plots_draws_the_three_plots_and_only_those(tmp_path):
    stamps, poses = _circle()
    ref = Trajectory(stamps, poses, "gt")
    results = [evaluate(ref, Trajectory(stamps, _circle(noise_m=0.05, seed=s)[1], f"est{s}"), EvalOptions())
               for s in (1, 2)]
    paths = write_plots(ref.positions, results, tmp_path)
    assert [p.name for p in paths] == list(PLOT_FILES)
    assert all(p.read_bytes()[:8] == PNG for p in paths)
    assert not (tmp_path / OFFSET_PLOT).exists() and not (tmp_path / GROUPS_PLOT).exists()
    with pytest.raises(InputError):
        write_plots(ref.positions, results, tmp_path)
