"""The plot job: read trajectories from any source (TUM, KITTI, ``LOG:/topic``...), align each to the first if
asked, and draw them (``plots.trajectories``).

``PlotJob`` -> ``run_plot`` -> ``PlotResult`` -> ``write_plot(result, folder, force)``. Not a batch command: it
reads no log of its own and has no configuration to resolve.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path

from ..errors import ConfigError, InputError
from ..evaluation.alignment import MODES, DegenerateAlignment, align
from ..evaluation.association import associate
from ..model.trajectory import Trajectory

PLOT_ALIGN_MODES = tuple(m for m in MODES if m != "scale")  # scale alone moves nothing into the first's frame


@dataclass(frozen=True)
class PlotJob:
    """Trajectories as named on the command line (the first is the one the others are aligned to)."""

    specs: tuple[str, ...]
    align: str = "none"
    t_max_diff_s: float = 0.01
    times: Path | None = None  # KITTI stamps
    rate_hz: float | None = None


@dataclass
class PlotResult:
    tracks: list[Trajectory]  # as drawn: the first as read, the others aligned to it when asked
    notes: list[str] = field(default_factory=list)


def align_to_first(tracks: Sequence[Trajectory], mode: str, max_diff_ns: int) -> tuple[list[Trajectory], list[str]]:
    """The first trajectory, then every other moved into its frame by ``mode`` (evaluation.alignment) fitted on
    their poses paired by stamp (nearest within ``max_diff_ns``); a note per alignment."""
    if mode not in PLOT_ALIGN_MODES:
        raise ConfigError(f"--align must be one of {', '.join(PLOT_ALIGN_MODES)}, got '{mode}'")
    first, out, notes = tracks[0], [tracks[0]], []
    for t in tracks[1:]:
        if mode == "none":
            out.append(t)
            continue
        try:
            pairs = associate(first, t, max_diff_ns)
        except InputError as err:
            raise InputError(f"cannot align {t.name} to {first.name}: no stamps pair within --t-max-diff "
                             f"{max_diff_ns * 1e-9:g} s ({_span(t)} against {_span(first)})") from err
        try:
            fit = align(pairs.ref.poses, pairs.est.poses, mode)
        except DegenerateAlignment as err:
            raise InputError(f"cannot align {t.name} to {first.name} by {mode}: its positions lie on a line or a "
                             "point; use --align origin or --align none") from err
        out.append(Trajectory(t.stamps_ns, fit.apply(t.poses), f"{t.name} ({mode}-aligned)", t.kind, t.gps))
        notes.append(f"{t.name}: aligned to {first.name} by {mode} over {len(pairs.ref)} paired poses"
                     + (f", scale {fit.scale:.6g}" if mode == "sim3" else ""))
    return out, notes


def _span(t: Trajectory) -> str:
    return f"{t.stamps_ns[0] * 1e-9:.3f}..{t.stamps_ns[-1] * 1e-9:.3f} s"


def run_plot(job: PlotJob) -> PlotResult:
    from ..io.sensors.sources import load_trajectory

    if not job.specs:
        raise ConfigError("give at least one trajectory to plot")
    tracks = []
    for spec in job.specs:
        t = load_trajectory(spec, times=job.times, rate_hz=job.rate_hz, stamp_options=True)
        tracks.append(Trajectory(t.stamps_ns, t.poses, spec, t.kind, t.gps))
    notes = []
    if job.align != "none" and len(tracks) == 1:
        notes.append(f"--align {job.align}: one trajectory, nothing to align to it")
    tracks, aligned = align_to_first(tracks, job.align, int(round(job.t_max_diff_s * 1e9)))
    return PlotResult(tracks, notes + aligned)


def write_plot(result: PlotResult, folder: Path, force: bool = False) -> list[Path]:
    """The pictures of ``plots.trajectories.PLOT_FILES`` into ``folder``; the paths written."""
    from ..plots.trajectories import write_trajectory_plots

    return write_trajectory_plots(result.tracks, folder, force)


def plot_files() -> tuple[str, ...]:
    from ..plots.trajectories import PLOT_FILES

    return PLOT_FILES


__all__ = ["PLOT_ALIGN_MODES", "PlotJob", "PlotResult", "align_to_first", "plot_files", "run_plot", "write_plot"]
