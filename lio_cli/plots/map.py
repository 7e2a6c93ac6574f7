"""A top view of a point map (``--map`` of ``lio odom`` and ``lio deskew``): points per cell of a grid seen from
above, on a log scale, so walls and poles (many points stacked in a cell) stand out from floor and ceiling (one
each); optionally the trajectory over it."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from ..model.trajectory import Trajectory
from .style import figure, save_png

SIZE_IN = (8.0, 8.0)
MAX_CELLS = 800  # along the map's longer side


def density_grid(points: np.ndarray, min_cell_m: float) -> tuple[np.ndarray, tuple[float, float, float, float], float]:
    """(points per cell (rows y, columns x), extent (x0, x1, y0, y1), cell size) of the finite points (N,3) seen
    from above; cells at least ``min_cell_m`` and at most ``MAX_CELLS`` along the longer side."""
    xy = np.asarray(points, dtype=np.float64)[:, :2]
    xy = xy[np.isfinite(xy).all(axis=1)]
    if len(xy) == 0:
        return np.zeros((1, 1)), (0.0, 1.0, 0.0, 1.0), 1.0
    lo, hi = xy.min(axis=0), xy.max(axis=0)
    cell = max(float(min_cell_m), float((hi - lo).max()) / MAX_CELLS, 1e-3)
    n = np.maximum(np.ceil((hi - lo) / cell).astype(int), 1)
    hi = lo + n * cell
    counts, _, _ = np.histogram2d(xy[:, 0], xy[:, 1], bins=(n[0], n[1]), range=((lo[0], hi[0]), (lo[1], hi[1])))
    return counts.T, (float(lo[0]), float(hi[0]), float(lo[1]), float(hi[1])), cell


def map_figure(points: np.ndarray, voxel_m: float | None = None, trajectory: Trajectory | None = None,
               title: str = "Map, top view"):
    """The map seen from above (points per cell, log scale), the trajectory in red with its start marked."""
    from matplotlib.colors import LogNorm

    counts, extent, cell = density_grid(points, voxel_m or 0.0)
    with figure(*SIZE_IN) as fig:
        ax = fig.add_subplot()
        ax.set_facecolor("white")
        shown = np.where(counts > 0, counts, np.nan)
        if np.isfinite(shown).any():
            image = ax.imshow(shown, origin="lower", extent=extent, cmap="viridis", interpolation="nearest",
                              norm=LogNorm(vmin=1.0, vmax=max(float(np.nanmax(shown)), 2.0)))
            fig.colorbar(image, ax=ax, shrink=0.8, label=f"points per {cell:.2g} m cell")
        if trajectory is not None and len(trajectory):
            p = trajectory.positions
            ax.plot(p[:, 0], p[:, 1], color="#d62728", lw=1.4, label="trajectory")
            ax.plot(p[0, 0], p[0, 1], "o", color="#d62728", ms=6, label="start")
            ax.legend(loc="upper right")
        ax.set_aspect("equal", adjustable="datalim")
        ax.grid(False)
        ax.set_xlabel("x [m]")
        ax.set_ylabel("y [m]")
        voxel = f", {voxel_m:g} m voxels" if voxel_m else ""
        ax.set_title(f"{title}: {len(points)} points{voxel}")
    return fig


def preview_path(map_path: Path) -> Path:
    """Where a map's top view goes: beside it, its suffix replaced by .png (``run.ply`` -> ``run.png``)."""
    return Path(map_path).with_suffix(".png")


def write_map_preview(points: np.ndarray, path: Path, force: bool = False, voxel_m: float | None = None,
                      trajectory: Trajectory | None = None) -> Path:
    return save_png(map_figure(points, voxel_m, trajectory), path, force)


__all__ = ["MAX_CELLS", "SIZE_IN", "density_grid", "map_figure", "preview_path", "write_map_preview"]
