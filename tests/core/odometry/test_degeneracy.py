"""The degeneracy check's building blocks give what their numpy/scipy originals give, to the bit."""

import subprocess
import sys

import numpy as np
import pytest

from lio_cli.core.odometry.degeneracy import scatter_matrices


def _einsum_scatter(nb: np.ndarray) -> np.ndarray:
    """The original formulation, on (n,k,d) neighbourhoods."""
    centred = nb - nb.mean(axis=1, keepdims=True)
    return np.einsum("nki,nkj->nij", centred, centred)


def _neighbourhoods(rng, n, k, d, kind):
    if kind == "random":
        pts = rng.normal(0.0, 20.0, (n * 4, d))
    elif kind == "planes":  # walls and floors: many coordinates exactly equal
        pts = rng.uniform(-5.0, 5.0, (n * 4, d))
        pts[::3, 0] = 2.5
        pts[1::3, -1] = 0.0
    else:  # one repeated point: every centred coordinate the same, zero or not
        pts = np.full((n * 4, d), 0.1)
    idx = rng.integers(0, len(pts), (n, k))
    return pts, idx


@pytest.mark.parametrize("d", [2, 3])
@pytest.mark.parametrize("kind", ["random", "planes", "repeated"])
@pytest.mark.parametrize("n,k", [(2, 21), (21, 20), (254, 20), (499, 20), (97, 5)])
def test_scatter_matrices_equal_einsum_to_the_bit(d, kind, n, k):
    rng = np.random.default_rng(n * 100 + k + d)
    pts, idx = _neighbourhoods(rng, n, k, d, kind)
    ours = scatter_matrices(pts[idx.T])
    ref = _einsum_scatter(pts[idx])
    assert ours.shape == ref.shape == (n, d, d)
    assert ours.tobytes() == ref.tobytes()  # -0.0 against 0.0 would differ here too
    w0, v0 = np.linalg.eigh(ref)
    w1, v1 = np.linalg.eigh(ours)
    assert w0.tobytes() == w1.tobytes() and v0.tobytes() == v1.tobytes()


def test_ckdtree_class_is_scipys_and_scipy_spatial_stays_unloaded():
    code = ("import sys; from lio_cli.core.kdtree import ckdtree_class; C = ckdtree_class(); "
            "assert 'scipy.spatial' not in sys.modules, 'scipy.spatial loaded'; "
            "from scipy.spatial import cKDTree, KDTree; assert C is cKDTree and issubclass(KDTree, C); "
            "d, i = C([[0.0, 0.0], [1.0, 1.0], [3.0, 0.0]]).query([[0.9, 1.2]], k=2); "
            "assert i.tolist() == [[1, 0]], i")
    subprocess.run([sys.executable, "-c", code], check=True)


def test_the_analysis_schedule_repeats_lio_odoms_and_reanalyses_a_retried_scan(monkeypatch):
    """lio odom (degeneracy_every_clear = degeneracy_every = 2) analyses every 2nd scan, and a scan registered
    again (a failed registration retried LiDAR-only, or a doubted one) again, as before the sparser schedule;
    deskew's clear-scene schedule (8) skips the scans between, but not a retried scan (its reuse would turn the
    directions by the motion between scans)."""
    import lio_cli.core.odometry.scan as scan
    from lio_cli.config.deskew import DeskewConfig
    from lio_cli.config.odom import OdomConfig
    from lio_cli.core.odometry.degeneracy import CLEAR_MARGIN, Degeneracy
    from lio_cli.core.odometry.state import DegeneracySchedule

    analysed = []

    def fake(points, planar, ratio):
        analysed.append(int(points[0, 0]))
        return Degeneracy([np.array([1.0, 0.0, 0.0])], 10 * CLEAR_MARGIN)  # clear by far

    monkeypatch.setattr(scan, "analyse_degeneracy", fake)
    for cfg, expected in ((OdomConfig(), [0, 0, 2, 4, 6, 8, 10]),
                          (DeskewConfig().odom_config("imu"), [0, 0, 8])):
        analysed.clear()
        schedule = DegeneracySchedule()
        for used in (0, 0, 1, 2, 3, 4, 5, 6, 7, 8, 9, 10):  # scan 0 registered twice (a retry)
            dirs = scan.scheduled_directions(schedule, np.full((5, 3), float(used)), np.eye(3), np.eye(4), used,
                                             False, False, cfg.fusion)
            assert len(dirs) == 1
        assert analysed == expected, (cfg.fusion.degeneracy_every_clear, analysed)
