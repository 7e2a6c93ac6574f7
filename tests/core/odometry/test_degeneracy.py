"""The degeneracy check's building blocks give what their numpy/scipy originals give: to the bit, or (the closed-form
eigen-decomposition) to rounding."""

import subprocess
import sys

import numpy as np
import pytest

from lio_cli.core.odometry.degeneracy import CLEAR_MARGIN, analyse_degeneracy, scatter_matrices, smallest_eigenvectors


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


def _spinning_scan(yaw: float, end_wall_m: float | None, beams: int = 16, columns: int = 1024) -> np.ndarray:
    """A 16-beam spinning LiDAR's scan (sensor frame, 0.6 m above the floor, turned by ``yaw`` about z) in a corridor
    2.4 m wide and 2.6 m high along x, ray-cast: walls, floor and ceiling; with an end wall ``end_wall_m`` ahead
    along the corridor (a scene that constrains every horizontal direction) unless None. Points of 100 m and more
    (no return) are dropped, as the range limits would."""
    elev = np.radians(np.linspace(-15.0, 15.0, beams))[:, None]
    azim = np.linspace(0.0, 2 * np.pi, columns, endpoint=False)[None, :]
    rays = np.stack(np.broadcast_arrays(np.cos(elev) * np.cos(azim), np.cos(elev) * np.sin(azim), np.sin(elev)),
                    axis=-1).reshape(-1, 3)
    c, s = np.cos(yaw), np.sin(yaw)
    R = np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])  # sensor -> corridor
    world = rays @ R.T
    planes = [(1, 1.2), (1, -1.2), (2, -0.6), (2, 2.0)] + ([(0, end_wall_m)] if end_wall_m is not None else [])
    t = np.full(len(rays), np.inf)
    for axis, offset in planes:
        with np.errstate(divide="ignore", invalid="ignore"):
            hit = offset / world[:, axis]
        t = np.where((hit > 0) & (hit < t), hit, t)
    keep = t < 100.0
    return rays[keep] * t[keep, None]


@pytest.mark.parametrize("yaw_deg", [0.0, 37.0, 90.0, 151.0])
def test_a_spinning_lidar_in_a_corridor_finds_its_axis_at_any_heading(yaw_deg):
    """A ray-cast 16-beam scan (16 384 points, thinned to 8192, dense near the sensor as a real one): the one
    degenerate direction is the corridor's axis in the sensor's frame, within half a degree, far below the ratio."""
    yaw = np.radians(yaw_deg)
    pts = _spinning_scan(yaw, None)
    found = analyse_degeneracy(pts, planar=False, ratio=0.025)
    assert len(found.directions) == 1
    axis = np.array([np.cos(yaw), -np.sin(yaw), 0.0])  # the corridor's x axis in the sensor frame
    d = found.directions[0]
    assert d[2] == 0.0 and abs(np.linalg.norm(d) - 1.0) < 1e-12
    assert np.degrees(np.arccos(min(1.0, abs(float(d @ axis))))) < 0.5
    assert 0.0 < found.margin < 0.3


@pytest.mark.parametrize("yaw_deg", [0.0, 37.0, 151.0])
def test_a_corridor_closed_by_a_wall_in_range_is_not_degenerate(yaw_deg):
    """The same scan with the corridor's end ahead: its normals constrain the axis, so nothing is flagged; 3 m
    ahead, the scene is clear by more than the margin that spaces the analyses out."""
    for wall_m, least_margin in ((6.0, 1.5), (3.0, CLEAR_MARGIN)):
        found = analyse_degeneracy(_spinning_scan(np.radians(yaw_deg), wall_m), planar=False, ratio=0.025)
        assert found.directions == []
        assert found.margin > least_margin


def test_a_planar_corridor_is_degenerate_along_its_axis_and_a_rectangular_room_is_not():
    """2D (a LaserScan's points, planar odometry): two parallel walls leave their direction free; a room with walls
    both ways does not."""
    rng = np.random.default_rng(3)
    x = rng.uniform(-15.0, 15.0, 2000)
    y = np.where(rng.integers(0, 2, 2000) == 0, -1.2, 1.2)
    c, s = np.cos(0.4), np.sin(0.4)
    corridor = np.column_stack([c * x - s * y, s * x + c * y, np.zeros(2000)])
    found = analyse_degeneracy(corridor, planar=True, ratio=0.025)
    assert len(found.directions) == 1
    assert abs(float(found.directions[0] @ [c, s, 0.0])) > np.cos(np.radians(0.5))
    u = rng.uniform(0.0, 8.0, 2000)
    side = rng.integers(0, 4, 2000)
    room = np.column_stack([np.where(side == 0, 0.0, np.where(side == 1, 8.0, u)),
                            np.where(side == 2, 0.0, np.where(side == 3, 5.0, u * 5.0 / 8.0)), np.zeros(2000)])
    found = analyse_degeneracy(room, planar=True, ratio=0.025)
    assert found.directions == [] and found.margin > CLEAR_MARGIN
