"""The degeneracy check's building blocks give what their numpy/scipy originals give: to the bit, or (the closed-form
eigen-decomposition) to rounding."""

import subprocess
import sys

import numpy as np
import pytest

from lio_cli.core.odometry.degeneracy import scatter_matrices, smallest_eigenvectors


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


@pytest.mark.parametrize("kind", ["random", "planes", "repeated"])
def test_smallest_eigenvectors_match_lapack_to_rounding(kind):
    rng = np.random.default_rng(7)
    pts, idx = _neighbourhoods(rng, 250, 20, 3, kind)
    S = scatter_matrices(pts[idx.T])
    if kind == "random":  # and flat neighbourhoods (surfaces) turned every way: U diag(l) U^T
        U = np.linalg.qr(rng.normal(size=(100, 3, 3)))[0]
        lam = rng.uniform(0.5, 1.0, (100, 3)) * [1e-4, 1.0, 3.0]
        S[:100] = np.einsum("nij,nj,nkj->nik", U, lam, U)
    w_ref, v_ref = np.linalg.eigh(S)
    w, v = smallest_eigenvectors(S)
    scale = np.maximum(w_ref[:, -1:], 1e-300)
    assert np.abs(w - w_ref).max(initial=0.0) <= 1e-12 * scale.max()
    apart = (w_ref[:, 1] - w_ref[:, 0]) > 1e-3 * w_ref[:, -1]  # where the smallest eigenvector is defined
    cos = np.abs(np.einsum("ni,ni->n", v[apart], v_ref[apart, :, 0]))
    assert np.all(np.abs(cos - 1.0) < 1e-9)
    w0, v0 = smallest_eigenvectors(np.zeros((2, 3, 3)))  # no spread at all: no normal
    assert np.all(w0 == 0.0) and np.all(v0 == 0.0)
