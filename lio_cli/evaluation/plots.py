"""PNG plots of an evaluation (matplotlib, Agg backend): top view, APE over time and distance, RPE histogram.

Each function writes one file atomically (through ``lio_cli.io.files.atomic_output``) and returns its path.
Figures are sized and lettered to be read at 100% zoom.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from ..io.files import atomic_output
from . import EvalResult

_DPI = 110
_COLORS = ["#1f77b4", "#d62728", "#2ca02c", "#ff7f0e", "#9467bd", "#8c564b", "#e377c2", "#17becf"]


def _pyplot():
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    plt.rcParams.update({"font.size": 12, "axes.titlesize": 14, "axes.labelsize": 12, "legend.fontsize": 11,
                         "axes.grid": True, "grid.alpha": 0.3})
    return plt


def _save(fig, path: Path, force: bool) -> Path:
    with atomic_output(path, force) as tmp:
        fig.savefig(tmp, format="png", dpi=_DPI, bbox_inches="tight")
    return path


def _label(name: str) -> str:
    return name if len(name) <= 40 else "..." + name[-37:]


def plot_top_view(ref_positions: np.ndarray, results: list[EvalResult], path: Path, force: bool = False) -> Path:
    """Ground truth and aligned estimates seen from above (x-y, equal axes)."""
    plt = _pyplot()
    fig, ax = plt.subplots(figsize=(8, 7))
    ax.plot(ref_positions[:, 0], ref_positions[:, 1], color="black", lw=2.2, ls="--", label="ground truth")
    for k, r in enumerate(results):
        p = r.est_aligned[:, :3, 3]
        ax.plot(p[:, 0], p[:, 1], color=_COLORS[k % len(_COLORS)], lw=1.6,
                label=f"{_label(r.name)} (APE rmse {r.stats['ape']['trans']['rmse']:.3g} m)")
    ax.plot(ref_positions[0, 0], ref_positions[0, 1], "o", color="black", ms=8, label="start")
    ax.set_aspect("equal", adjustable="datalim")
    ax.set_xlabel("x [m]")
    ax.set_ylabel("y [m]")
    mode = results[0].alignment.mode if results else "none"
    ax.set_title(f"Top view (estimates aligned: {mode})")
    ax.legend(loc="best")
    try:
        return _save(fig, path, force)
    finally:
        plt.close(fig)


def plot_ape(results: list[EvalResult], path: Path, force: bool = False) -> Path:
    """APE translation over time (top) and over distance travelled along the ground truth (bottom)."""
    plt = _pyplot()
    fig, (ax_t, ax_d) = plt.subplots(2, 1, figsize=(10, 7.5))
    t0 = min(int(r.association.ref.stamps_ns[0]) for r in results)
    for k, r in enumerate(results):
        color = _COLORS[k % len(_COLORS)]
        t = (r.association.ref.stamps_ns - t0) / 1e9
        ref_p = r.association.ref.positions
        dist = np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(ref_p, axis=0), axis=1))])
        e = r.ape["trans"]
        ax_t.plot(t, e, color=color, lw=1.3, label=_label(r.name))
        ax_d.plot(dist, e, color=color, lw=1.3, label=_label(r.name))
    ax_t.set_xlabel("time since start [s]")
    ax_d.set_xlabel("distance travelled along ground truth [m]")
    for ax in (ax_t, ax_d):
        ax.set_ylabel("APE translation [m]")
        ax.set_ylim(bottom=0.0)
        ax.legend(loc="upper left")
    ax_t.set_title(f"Absolute position error (alignment: {results[0].alignment.mode})")
    fig.tight_layout()
    try:
        return _save(fig, path, force)
    finally:
        plt.close(fig)


def plot_rpe_histogram(results: list[EvalResult], path: Path, force: bool = False) -> Path:
    """Histograms of RPE translation and rotation errors."""
    plt = _pyplot()
    fig, (ax_t, ax_r) = plt.subplots(1, 2, figsize=(12, 5))
    o = results[0].options
    # shared bins, so estimates compare bar for bar
    bins_t = np.histogram_bin_edges(np.concatenate([r.rpe["trans"] for r in results]), bins=40)
    bins_r = np.histogram_bin_edges(np.concatenate([r.rpe["rot"] for r in results]), bins=40)
    for k, r in enumerate(results):
        color = _COLORS[k % len(_COLORS)]
        ax_t.hist(r.rpe["trans"], bins=bins_t, color=color, alpha=0.5, label=_label(r.name))
        ax_r.hist(r.rpe["rot"], bins=bins_r, color=color, alpha=0.5, label=_label(r.name))
    ax_t.set_xlabel("RPE translation [m]")
    ax_r.set_xlabel("RPE rotation [deg]")
    for ax in (ax_t, ax_r):
        ax.set_ylabel("pose pairs")
        ax.legend(loc="upper right")
    unit = "frame" + ("s" if o.delta != 1 else "") if o.delta_unit == "frames" else o.delta_unit
    fig.suptitle(f"Relative pose error over {o.delta:g} {unit}{' (all pairs)' if o.all_pairs else ''}", fontsize=14)
    fig.tight_layout()
    try:
        return _save(fig, path, force)
    finally:
        plt.close(fig)


PLOT_FILES = ("top_view.png", "ape.png", "rpe_histogram.png")


def write_plots(ref_positions: np.ndarray, results: list[EvalResult], folder: Path, force: bool = False) -> list[Path]:
    """All plots into ``folder`` (which must exist)."""
    return [
        plot_top_view(ref_positions, results, folder / PLOT_FILES[0], force),
        plot_ape(results, folder / PLOT_FILES[1], force),
        plot_rpe_histogram(results, folder / PLOT_FILES[2], force),
    ]
