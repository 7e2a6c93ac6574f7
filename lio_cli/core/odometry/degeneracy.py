"""Degenerate geometry: translation directions a scan's surfaces do not constrain (a corridor's axis)."""

from __future__ import annotations

import math
from typing import NamedTuple

import numpy as np

from ..kdtree import ckdtree_class

_DEGENERACY_MAX_POINTS = 8192  # the constraint analysis needs surfaces, not every point of a 128-beam scan
CLEAR_MARGIN = 4.0  # a scan whose weakest direction is this many times above the ratio is far from degenerate


class Degeneracy(NamedTuple):
    directions: list[np.ndarray]  # degenerate horizontal directions (the points' frame)
    margin: float  # weakest / strongest horizontal eigenvalue over the ratio (< 1: degenerate; 0: no surfaces)


def degenerate_directions(points: np.ndarray, planar: bool, ratio: float, k: int = 20,
                          queries: int = 250) -> list[np.ndarray]:
    """Horizontal translation directions the scan's surfaces do not constrain (in the points' frame): see
    ``analyse_degeneracy``."""
    return analyse_degeneracy(points, planar, ratio, k, queries).directions


def analyse_degeneracy(points: np.ndarray, planar: bool, ratio: float, k: int = 20,
                       queries: int = 250) -> Degeneracy:
    """Horizontal translation directions the scan's surfaces do not constrain, and how far the scan is from that.

    Normals from local PCA over ``k`` neighbours in the full scan (at up to ``queries`` sample points) give
    the point-to-plane information ``sum n n^T`` on translation. Its horizontal (x-y) block is examined: an
    eigenvalue below ``ratio`` times the larger one marks its eigenvector as degenerate (a corridor's axis).
    The vertical is left out on purpose: sparse spinning LiDARs see floor and ceiling only at grazing
    angles, so z is weakly constrained in almost every scan and is better left to the registration.
    """
    dims = 2 if planar else 3
    pts = points[:: max(1, math.ceil(len(points) / _DEGENERACY_MAX_POINTS)), :dims]  # denser: every n-th point
    if len(pts) < k + 1:
        return Degeneracy([], 0.0)
    step = max(1, len(pts) // queries)  # deterministic, evenly spread sample
    cKDTree = ckdtree_class()  # here, not at import: scipy is a tenth of a second of start-up

    # built for a few hundred queries: leaves of 64 build faster than 16 (the neighbours are exact whatever the leaf size)
    tree = cKDTree(pts, leafsize=64, balanced_tree=False, compact_nodes=False)
    _, nn = tree.query(pts[::step], k=k)
    scatter = scatter_matrices(pts[nn.T])
    if dims == 3:
        w, normals = smallest_eigenvectors(scatter)
    else:
        w, v = np.linalg.eigh(scatter)
        normals = v[:, :, 0]  # smallest eigenvalue's vector
    # only neighbourhoods that are surfaces (not lines or blobs) carry a reliable normal
    surface = (w[:, 1] - w[:, 0]) > 0.3 * np.maximum(w[:, -1], 1e-12)
    info = normals[surface].T @ normals[surface]
    lam, vec = np.linalg.eigh(info[:2, :2])
    if lam[-1] <= 0:
        return Degeneracy([], 0.0)
    margin = float(lam[0] / (ratio * lam[-1]))
    if lam[0] >= ratio * lam[-1]:
        return Degeneracy([], margin)
    return Degeneracy([np.array([vec[0, 0], vec[1, 0], 0.0])], margin)


def scatter_matrices(neighbours: np.ndarray) -> np.ndarray:
    """Scatter matrices (n,d,d) about their mean of n neighbourhoods of k points given as (k,n,d): the bits of
    ``c = nb - nb.mean(axis=1, keepdims=True); np.einsum("nki,nkj->nij", c, c)`` for ``nb`` (n,k,d).

    For n >= 2 both sum over the k neighbours one after the other from the first (numpy's reduction over a
    middle axis, einsum's sum of products; a single neighbourhood takes einsum down another path), so the same
    sums taken over the outer axis of this layout, where each step adds whole contiguous rows, give the same
    bits faster (einsum's sums start from 0.0, which only turns an all-zero sum's -0.0 into
    0.0: hence the ``+ 0.0``). ``degenerate_directions`` has at least k + 1 neighbourhoods."""
    k, n, d = neighbours.shape
    mean = np.add.reduce(neighbours, axis=0)
    mean /= k
    c = neighbours - mean
    out = np.empty((n, d, d))
    for i in range(d):
        for j in range(i + 1):
            s = np.add.reduce(c[:, :, i] * c[:, :, j], axis=0)
            s += 0.0
            out[:, i, j] = out[:, j, i] = s
    return out


def smallest_eigenvectors(S: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(eigenvalues ascending (n,3), the smallest one's unit eigenvector (n,3)) of symmetric 3x3 matrices (n,3,3),
    in closed form, cheaper than ``np.linalg.eigh``'s LAPACK call per matrix.

    The eigenvalues by the trigonometric solution of the characteristic cubic (Smith 1961), to the rounding of the
    largest one; the vector as the longest cross product of two rows of ``S - lo I``, accurate wherever the
    smallest eigenvalue stands apart from the middle one (a surface). All-equal eigenvalues give a zero vector."""
    a00, a11, a22 = S[:, 0, 0], S[:, 1, 1], S[:, 2, 2]
    a01, a02, a12 = S[:, 0, 1], S[:, 0, 2], S[:, 1, 2]
    q = (a00 + a11 + a22) / 3.0
    b00, b11, b22 = a00 - q, a11 - q, a22 - q
    p = np.sqrt((b00 * b00 + b11 * b11 + b22 * b22 + 2.0 * (a01 * a01 + a02 * a02 + a12 * a12)) / 6.0)
    det = b00 * (b11 * b22 - a12 * a12) - a01 * (a01 * b22 - a12 * a02) + a02 * (a01 * a12 - b11 * a02)
    half_det = det / (2.0 * np.where(p > 0, p, 1.0) ** 3)  # det((S - q I) / p) / 2, in [-1, 1]
    phi = np.arccos(np.clip(half_det, -1.0, 1.0)) / 3.0
    hi = q + 2.0 * p * np.cos(phi)
    lo = q + 2.0 * p * np.cos(phi + 2.0 * np.pi / 3.0)
    w = np.stack([lo, 3.0 * q - hi - lo, hi], axis=1)
    x0, x1, x2 = a00 - lo, a11 - lo, a22 - lo  # rows (x0, a01, a02), (a01, x1, a12), (a02, a12, x2)
    c01 = np.stack([a01 * a12 - a02 * x1, a02 * a01 - x0 * a12, x0 * x1 - a01 * a01])
    c02 = np.stack([a01 * x2 - a02 * a12, a02 * a02 - x0 * x2, x0 * a12 - a01 * a02])
    c12 = np.stack([x1 * x2 - a12 * a12, a12 * a02 - a01 * x2, a01 * a12 - x1 * a02])
    v, n2 = c01, np.einsum("in,in->n", c01, c01)
    for c in (c02, c12):
        c_n2 = np.einsum("in,in->n", c, c)
        longer = c_n2 > n2
        v, n2 = np.where(longer, c, v), np.where(longer, c_n2, n2)
    return w, (v / np.sqrt(np.where(n2 > 0, n2, 1.0))).T
