"""PNG plots of an evaluation (matplotlib, Agg backend): top view, APE over time and distance, RPE histogram;
with --estimate-offset the error over the searched offsets, with groups the metrics of every run per group.

Each function writes one file atomically (``style.save_tight``) and returns its path.
Figures are sized and lettered to be read at 100% zoom.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from ..evaluation import EvalResult
from .style import color as color_of, pyplot, save_tight, short_label






def plot_top_view(ref_positions: np.ndarray, results: list[EvalResult], path: Path, force: bool = False,
                  ref_as_points: bool = False) -> Path:
    """Ground truth and aligned estimates seen from above (x-y, equal axes); a GPS reference as points."""
    plt = pyplot()
    fig, ax = plt.subplots(figsize=(8, 7))
    if ref_as_points:
        ax.plot(ref_positions[:, 0], ref_positions[:, 1], "o", color="black", ms=3.5, alpha=0.6,
                label="GPS fixes (east, north)")
    else:
        ax.plot(ref_positions[:, 0], ref_positions[:, 1], color="black", lw=2.2, ls="--", label="ground truth")
    for k, r in enumerate(results):
        p = r.est_aligned[:, :3, 3]
        ax.plot(p[:, 0], p[:, 1], color=color_of(k), lw=1.6,
                label=f"{short_label(r.name)} (APE rmse {r.stats['ape']['trans']['rmse']:.3g} m)")
    ax.plot(ref_positions[0, 0], ref_positions[0, 1], "o", color="black", ms=8, label="start")
    ax.set_aspect("equal", adjustable="datalim")
    ax.set_xlabel("east [m]" if ref_as_points else "x [m]")
    ax.set_ylabel("north [m]" if ref_as_points else "y [m]")
    mode = results[0].alignment.mode if results else "none"
    ax.set_title(f"Top view (estimates aligned: {mode})")
    ax.legend(loc="best")
    return save_tight(fig, path, force)


def plot_ape(results: list[EvalResult], path: Path, force: bool = False) -> Path:
    """APE translation over time (top) and over distance travelled along the ground truth (bottom)."""
    plt = pyplot()
    fig, (ax_t, ax_d) = plt.subplots(2, 1, figsize=(10, 7.5))
    t0 = min(int(r.association.ref.stamps_ns[0]) for r in results)
    for k, r in enumerate(results):
        color = color_of(k)
        t = (r.association.ref.stamps_ns - t0) / 1e9
        ref_p = r.association.ref.positions
        dist = np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(ref_p, axis=0), axis=1))])
        e = r.ape["trans"]
        ax_t.plot(t, e, color=color, lw=1.3, label=short_label(r.name))
        ax_d.plot(dist, e, color=color, lw=1.3, label=short_label(r.name))
    ax_t.set_xlabel("time since start [s]")
    ax_d.set_xlabel("distance travelled along ground truth [m]")
    for ax in (ax_t, ax_d):
        ax.set_ylabel("APE translation [m]")
        ax.set_ylim(bottom=0.0)
        ax.legend(loc="upper left")
    ax_t.set_title(f"Absolute position error (alignment: {results[0].alignment.mode})")
    fig.tight_layout()
    return save_tight(fig, path, force)


def plot_rpe_histogram(results: list[EvalResult], path: Path, force: bool = False) -> Path:
    """Histograms of RPE translation and rotation errors."""
    plt = pyplot()
    with_rot = [r for r in results if "rot" in r.rpe]  # position-only (GPS) runs have no rotation error
    fig, axes = plt.subplots(1, 2 if with_rot else 1, figsize=(12, 5) if with_rot else (7, 5), squeeze=False)
    ax_t, ax_r = axes[0][0], axes[0][-1] if with_rot else None
    o = results[0].options
    # shared bins, so estimates compare bar for bar
    bins_t = np.histogram_bin_edges(np.concatenate([r.rpe["trans"] for r in results]), bins=40)
    bins_r = np.histogram_bin_edges(np.concatenate([r.rpe["rot"] for r in with_rot]), bins=40) if with_rot else None
    for k, r in enumerate(results):
        color = color_of(k)
        ax_t.hist(r.rpe["trans"], bins=bins_t, color=color, alpha=0.5, label=short_label(r.name))
        if ax_r is not None and "rot" in r.rpe:
            ax_r.hist(r.rpe["rot"], bins=bins_r, color=color, alpha=0.5, label=short_label(r.name))
    ax_t.set_xlabel("RPE translation [m]")
    if ax_r is not None:
        ax_r.set_xlabel("RPE rotation [deg]")
    for ax in axes[0]:
        ax.set_ylabel("pose pairs")
        ax.legend(loc="upper right")
    unit = "frame" + ("s" if o.delta != 1 else "") if o.delta_unit == "frames" else o.delta_unit
    fig.suptitle(f"Relative pose error over {o.delta:g} {unit}{' (all pairs)' if o.all_pairs else ''}", fontsize=14)
    fig.tight_layout()
    return save_tight(fig, path, force)


def plot_offsets(results: list[EvalResult], path: Path, force: bool = False) -> Path:
    """Per estimate with an estimated offset: sampled matches and aligned error over the searched offsets (top),
    and the error close to the estimate (bottom)."""
    plt = pyplot()
    runs = [r for r in results if r.offset is not None]
    fig, (ax_m, ax_z) = plt.subplots(2, 1, figsize=(10, 8))
    ax_e = ax_m.twinx()
    for k, r in enumerate(runs):
        f, color = r.offset, color_of(k)
        ax_m.plot(f.grid_ns / 1e9, f.grid_matches / max(f.sampled, 1) * 100.0, color=color, lw=1.0, alpha=0.45)
        ax_e.semilogy(f.curve_ns / 1e9, f.curve_cost, ".", color=color, ms=4, label=short_label(r.name))
        rel_ms = (f.zoom_ns - f.offset_ns) / 1e6
        ax_z.plot(rel_ms, f.zoom_cost, color=color, lw=1.5,
                  label=f"{short_label(r.name)}: {f.offset_s:+.6f} s, rmse {f.rmse_m:.3g} m")
        ax_z.axvline(0.0, color=color, lw=0.8, ls=":")
    ax_m.set_xlabel("offset added to the estimate's stamps [s]")
    ax_m.set_ylabel("sampled stamps paired [%] (lines)")
    ax_e.set_ylabel("aligned error / its minimum (dots)")
    ax_e.legend(loc="upper right")
    ax_m.set_title("Time-offset search: pairs, then aligned error")
    ax_z.set_xlabel("offset relative to each estimate [ms]")
    ax_z.set_ylabel("aligned error / its minimum")
    ax_z.legend(loc="upper center")
    fig.tight_layout()
    return save_tight(fig, path, force)


_GROUP_PANELS = (("ape_trans_rmse", "APE translation rmse [m]"), ("rpe_trans_rmse", "RPE translation rmse [m]"),
                 ("ape_rot_rmse", "APE rotation rmse [deg]"))


def plot_groups(groups, results: list[EvalResult], path: Path, force: bool = False) -> Path:
    """Per group: every run's value (dots) with mean +- std (bar) for APE/RPE translation and APE rotation."""
    plt = pyplot()
    metrics = {r.name: r.flat_metrics() for r in results}
    panels = [(k, t) for k, t in _GROUP_PANELS if any(g.metrics[k]["n"] for g in groups)]
    fig, axes = plt.subplots(1, len(panels), figsize=(4.5 * len(panels) + 1, 5), squeeze=False)
    for ax, (key, title) in zip(axes[0], panels):
        for k, g in enumerate(groups):
            color = color_of(k)
            vals = [metrics[m][key] for m in g.runs if metrics[m][key] is not None]
            ax.plot(np.full(len(vals), k) + np.linspace(-0.12, 0.12, len(vals)), vals, "o", color=color, alpha=0.6)
            s = g.metrics[key]
            if s["n"]:
                ax.errorbar([k + 0.3], [s["mean"]], yerr=[[s["std"] or 0.0]], fmt="s", color=color, capsize=6, ms=7)
        ax.set_xticks(range(len(groups)), [f"{short_label(g.name)}\n({len(g.runs)} runs)" for g in groups])
        ax.set_xlim(-0.6, len(groups) - 0.4)
        ax.set_ylabel(title)
        ax.set_ylim(bottom=0.0)
    fig.suptitle("Statistics over runs: runs (dots), mean +- std (squares)", fontsize=14)
    fig.tight_layout()
    return save_tight(fig, path, force)


PLOT_FILES = ("top_view.png", "ape.png", "rpe_histogram.png")
OFFSET_PLOT = "offset.png"
GROUPS_PLOT = "groups.png"


def write_plots(ref_positions: np.ndarray, results: list[EvalResult], folder: Path, force: bool = False,
                ref_as_points: bool = False, groups=None) -> list[Path]:
    """All plots into ``folder`` (which must exist); offsets and groups (``GroupStats``) only when there."""
    paths = [
        plot_top_view(ref_positions, results, folder / PLOT_FILES[0], force, ref_as_points),
        plot_ape(results, folder / PLOT_FILES[1], force),
        plot_rpe_histogram(results, folder / PLOT_FILES[2], force),
    ]
    if any(r.offset is not None for r in results):
        paths.append(plot_offsets(results, folder / OFFSET_PLOT, force))
    if groups:
        paths.append(plot_groups(groups, results, folder / GROUPS_PLOT, force))
    return paths
