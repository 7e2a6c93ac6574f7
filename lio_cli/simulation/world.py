"""Static worlds made of axis-aligned boxes, vertical cylinders and horizontal planes, and a vectorised
ray caster over them.

Everything is in the ``world`` frame (z up, metres). Ray casting is pure numpy: rays are processed in
chunks, each chunk tested against every primitive at once by broadcasting (slab test for boxes, a
quadratic in x-y for cylinders, one division for planes).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

_EPS_M = 1e-6  # hits closer than this to the ray origin are ignored
_CHUNK_RAYS = 4096
_SECTORS = 64  # azimuth sectors for culling


@dataclass
class World:
    """A static scene. Boxes are solid (``lo``/``hi`` corners), cylinders are vertical and solid, planes are
    infinite horizontal surfaces at height ``z`` (a floor, a ceiling). ``reflectivity`` per primitive in
    [0, 1] feeds the simulated intensity."""

    name: str
    box_lo: np.ndarray = field(default_factory=lambda: np.zeros((0, 3)))
    box_hi: np.ndarray = field(default_factory=lambda: np.zeros((0, 3)))
    box_refl: np.ndarray = field(default_factory=lambda: np.zeros(0))
    cyl: np.ndarray = field(default_factory=lambda: np.zeros((0, 5)))  # cx, cy, radius, z_lo, z_hi
    cyl_refl: np.ndarray = field(default_factory=lambda: np.zeros(0))
    plane_z: np.ndarray = field(default_factory=lambda: np.zeros(0))
    plane_refl: np.ndarray = field(default_factory=lambda: np.zeros(0))

    def add_box(self, lo, hi, refl: float = 0.5) -> None:
        lo, hi = np.minimum(lo, hi), np.maximum(lo, hi)
        self.box_lo = np.vstack([self.box_lo, np.asarray(lo, float)[None]])
        self.box_hi = np.vstack([self.box_hi, np.asarray(hi, float)[None]])
        self.box_refl = np.append(self.box_refl, refl)

    def add_cylinder(self, cx: float, cy: float, radius: float, z_lo: float, z_hi: float, refl: float = 0.5) -> None:
        self.cyl = np.vstack([self.cyl, np.array([[cx, cy, radius, z_lo, z_hi]], float)])
        self.cyl_refl = np.append(self.cyl_refl, refl)

    def add_plane(self, z: float, refl: float = 0.3) -> None:
        self.plane_z = np.append(self.plane_z, float(z))
        self.plane_refl = np.append(self.plane_refl, refl)

    @property
    def n_primitives(self) -> int:
        return len(self.box_lo) + len(self.cyl) + len(self.plane_z)

    @property
    def reflectivity(self) -> np.ndarray:
        """Reflectivity by primitive id (boxes, then cylinders, then planes)."""
        return np.concatenate([self.box_refl, self.cyl_refl, self.plane_refl])


def _ray_boxes(o: np.ndarray, d: np.ndarray, lo: np.ndarray, hi: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Nearest entry distance (n,) of rays into any box, and the box index (-1: none)."""
    n = len(o)
    if len(lo) == 0:
        return np.full(n, np.inf), np.full(n, -1, np.int64)
    safe = np.where(np.abs(d) < 1e-12, 1e-12, d)
    inv = 1.0 / safe
    t1 = (lo[None, :, :] - o[:, None, :]) * inv[:, None, :]
    t2 = (hi[None, :, :] - o[:, None, :]) * inv[:, None, :]
    t_near = np.minimum(t1, t2).max(axis=2)
    t_far = np.maximum(t1, t2).min(axis=2)
    hit = (t_near <= t_far) & (t_near > _EPS_M)
    t = np.where(hit, t_near, np.inf)
    idx = t.argmin(axis=1)
    best = t[np.arange(n), idx]
    return best, np.where(np.isfinite(best), idx, -1)


def _ray_cylinders(o: np.ndarray, d: np.ndarray, cyl: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Nearest hit (n,) on the side or caps of vertical cylinders, and the cylinder index (-1: none)."""
    n = len(o)
    if len(cyl) == 0:
        return np.full(n, np.inf), np.full(n, -1, np.int64)
    cx, cy, r, z_lo, z_hi = (cyl[:, i][None, :] for i in range(5))
    ox, oy, oz = o[:, 0:1], o[:, 1:2], o[:, 2:3]
    dx, dy, dz = d[:, 0:1], d[:, 1:2], d[:, 2:3]
    px, py = ox - cx, oy - cy
    a = dx * dx + dy * dy
    b = px * dx + py * dy
    c = px * px + py * py - r * r
    disc = b * b - a * c
    with np.errstate(invalid="ignore", divide="ignore"):
        sq = np.sqrt(np.where(disc >= 0.0, disc, np.nan))
        t_side = (-b - sq) / a
    z_side = oz + t_side * dz
    t_side = np.where((t_side > _EPS_M) & (z_side >= z_lo) & (z_side <= z_hi), t_side, np.inf)
    # caps (top seen from above, bottom from below)
    safe_dz = np.where(np.abs(dz) < 1e-12, 1e-12, dz)
    best = t_side
    for zc in (z_lo, z_hi):
        t_cap = (zc - oz) / safe_dz
        qx, qy = px + t_cap * dx, py + t_cap * dy
        ok = (t_cap > _EPS_M) & (qx * qx + qy * qy <= r * r)
        best = np.minimum(best, np.where(ok, t_cap, np.inf))
    best = np.where(np.isnan(best), np.inf, best)
    idx = best.argmin(axis=1)
    t = best[np.arange(n), idx]
    return t, np.where(np.isfinite(t), idx, -1)


def _ray_planes(o: np.ndarray, d: np.ndarray, plane_z: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    n = len(o)
    if len(plane_z) == 0:
        return np.full(n, np.inf), np.full(n, -1, np.int64)
    dz = d[:, 2:3]
    safe = np.where(np.abs(dz) < 1e-12, 1e-12, dz)
    t = (plane_z[None, :] - o[:, 2:3]) / safe
    t = np.where(t > _EPS_M, t, np.inf)
    idx = t.argmin(axis=1)
    best = t[np.arange(n), idx]
    return best, np.where(np.isfinite(best), idx, -1)


def raycast(world: World, origins: np.ndarray, dirs: np.ndarray, max_range_m: float = np.inf) -> tuple[np.ndarray, np.ndarray]:
    """Distance along each unit ray to the first surface (``inf`` when nothing within ``max_range_m``) and
    the primitive id hit (boxes, then cylinders, then planes; -1 for none).

    ``origins`` and ``dirs`` are (N,3) (``origins`` may be (3,) for a common origin); ``dirs`` must be unit.
    Rays are expected to start close together (one scan): boxes and cylinders are culled by range and
    then by azimuth sector as seen from the rays' mean origin, so each ray meets only the few primitives
    in its direction.
    """
    dirs = np.asarray(dirs, dtype=np.float64)
    origins = np.broadcast_to(np.asarray(origins, dtype=np.float64), dirs.shape)
    n = len(dirs)
    ranges = np.full(n, np.inf)
    ids = np.full(n, -1, np.int64)
    if n == 0:
        return ranges, ids
    n_box, n_cyl = len(world.box_lo), len(world.cyl)
    # every solid primitive's x-y footprint as a rectangle (cylinders by their bounding square)
    foot_lo = np.vstack([world.box_lo[:, :2], world.cyl[:, :2] - world.cyl[:, 2:3]])
    foot_hi = np.vstack([world.box_hi[:, :2], world.cyl[:, :2] + world.cyl[:, 2:3]])
    centre = origins.mean(axis=0)
    spread = float(np.linalg.norm(origins[:, :2] - centre[:2], axis=1).max()) + 1e-6
    lo_i, hi_i = foot_lo - spread, foot_hi + spread  # inflated: valid for every origin of the batch
    gap = np.linalg.norm(np.maximum(0.0, np.maximum(lo_i - centre[:2], centre[:2] - hi_i)), axis=1)
    reach = gap <= max_range_m
    inside = reach & (gap == 0.0)  # the origin is above/below this footprint: any azimuth may hit it
    # azimuth interval of each footprint seen from the centre
    corners = np.stack([np.stack([lo_i[:, 0], lo_i[:, 1]], 1), np.stack([lo_i[:, 0], hi_i[:, 1]], 1),
                        np.stack([hi_i[:, 0], lo_i[:, 1]], 1), np.stack([hi_i[:, 0], hi_i[:, 1]], 1)], axis=1)
    mid = 0.5 * (lo_i + hi_i) - centre[:2]
    a_mid = np.arctan2(mid[:, 1], mid[:, 0])
    a_c = np.arctan2(corners[..., 1] - centre[1], corners[..., 0] - centre[0])
    rel = (a_c - a_mid[:, None] + np.pi) % (2 * np.pi) - np.pi
    rel_lo, rel_hi = rel.min(axis=1), rel.max(axis=1)
    # sectors pay off for many rays among many primitives; otherwise one pass over everything is quicker
    sectors = min(_SECTORS, n // 256) if n_box + n_cyl > 16 else 1
    sectors = max(sectors, 1)
    half = np.pi / sectors
    sec_mid = -np.pi + (2 * np.arange(sectors) + 1) * half
    d_ang = (sec_mid[None, :] - a_mid[:, None] + np.pi) % (2 * np.pi) - np.pi  # (M,S)
    cand = reach[:, None] & (inside[:, None] | ((d_ang >= rel_lo[:, None] - half) & (d_ang <= rel_hi[:, None] + half)))
    if sectors == 1:
        cand = reach[:, None]
    ray_az = np.arctan2(dirs[:, 1], dirs[:, 0])
    ray_sec = np.minimum(((ray_az + np.pi) / (2 * half)).astype(np.int64), sectors - 1)
    order = np.argsort(ray_sec, kind="stable")
    bounds = np.searchsorted(ray_sec[order], np.arange(sectors + 1))
    cyl_id = np.arange(n_cyl) + n_box
    for k in range(sectors):
        sel_all = order[bounds[k]:bounds[k + 1]]
        if len(sel_all) == 0:
            continue
        prims = np.flatnonzero(cand[:, k])
        boxes, cyls = prims[prims < n_box], prims[prims >= n_box] - n_box
        for s in range(0, len(sel_all), _CHUNK_RAYS):
            sel = sel_all[s:s + _CHUNK_RAYS]
            o, d = origins[sel], dirs[sel]
            tb, ib = _ray_boxes(o, d, world.box_lo[boxes], world.box_hi[boxes])
            tc, ic = _ray_cylinders(o, d, world.cyl[cyls])
            tp, ip = _ray_planes(o, d, world.plane_z)
            t = np.stack([tb, tc, tp])
            which = t.argmin(axis=0)
            best = t[which, np.arange(len(sel))]
            prim = np.choose(which, [np.where(ib >= 0, boxes[np.maximum(ib, 0)] if len(boxes) else -1, -1),
                                     np.where(ic >= 0, cyl_id[cyls][np.maximum(ic, 0)] if len(cyls) else -1, -1),
                                     np.where(ip >= 0, ip + n_box + n_cyl, -1)])
            far = best > max_range_m
            ranges[sel] = np.where(far, np.inf, best)
            ids[sel] = np.where(far, -1, prim)
    return ranges, ids


def footprint_clearance(world: World, xy: np.ndarray, z_lo: float = 0.0, z_hi: float = 2.0) -> np.ndarray:
    """Horizontal distance (N,) from each x-y position to the nearest box or cylinder that overlaps the
    height band [z_lo, z_hi] (the platform's body); negative inside an obstacle."""
    xy = np.atleast_2d(np.asarray(xy, dtype=np.float64))
    best = np.full(len(xy), np.inf)
    lo, hi = world.box_lo, world.box_hi
    band = (lo[:, 2] < z_hi) & (hi[:, 2] > z_lo) if len(lo) else np.zeros(0, bool)
    if band.any():
        blo, bhi = lo[band, :2], hi[band, :2]
        outside = np.maximum(0.0, np.maximum(blo[None] - xy[:, None], xy[:, None] - bhi[None]))
        dist_out = np.linalg.norm(outside, axis=2)
        depth = np.minimum(xy[:, None] - blo[None], bhi[None] - xy[:, None]).min(axis=2)
        dist = np.where(dist_out > 0.0, dist_out, -np.maximum(depth, 0.0))
        best = np.minimum(best, dist.min(axis=1))
    cyl = world.cyl
    cband = (cyl[:, 3] < z_hi) & (cyl[:, 4] > z_lo) if len(cyl) else np.zeros(0, bool)
    if cband.any():
        c = cyl[cband]
        d = np.linalg.norm(xy[:, None, :] - c[None, :, :2], axis=2) - c[None, :, 2]
        best = np.minimum(best, d.min(axis=1))
    return best
