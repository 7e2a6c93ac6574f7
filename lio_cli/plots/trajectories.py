"""Pictures of trajectories without ground truth (``lio plot``, ``lio odom --plot``): the top view, x/y/z and
roll/pitch/yaw over time, and speed over time, any number of trajectories overlaid with a legend.

Time runs from the earliest start when the trajectories overlap in time, else each from its own start. A
position-only trajectory (GPS) has no line in the roll/pitch/yaw picture.
"""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path

import numpy as np

from ..geometry import roll_pitch_yaw
from ..io.files.atomic import make_folder
from ..model.trajectory import Trajectory
from .style import color, figure, save_png, short_label, stride

PLOT_FILES = ("trajectories_xy.png", "xyz.png", "rpy.png", "speed.png")  # what ``write_trajectory_plots`` writes
SIZES_IN = {"trajectories_xy.png": (8.0, 7.0), "xyz.png": (10.0, 8.0), "rpy.png": (10.0, 8.0),
            "speed.png": (10.0, 4.5)}


def time_origin(tracks: Sequence[Trajectory]) -> tuple[list[int], str]:
    """(per trajectory the stamp its time axis starts at, the axis label): one shared start when every trajectory
    overlaps the first in time, else each its own."""
    spans = [(int(t.stamps_ns[0]), int(t.stamps_ns[-1])) for t in tracks]
    s0, e0 = spans[0]
    if all(s <= e0 and e >= s0 for s, e in spans):
        start = min(s for s, _ in spans)
        return [start] * len(tracks), "time since the start [s]"
    return [s for s, _ in spans], "time since each trajectory's start [s] (their times do not overlap)"


def _seconds(t: Trajectory, t0_ns: int) -> np.ndarray:
    return (np.asarray(t.stamps_ns, dtype=np.int64) - t0_ns) * 1e-9


def top_view_figure(tracks: Sequence[Trajectory], title: str = "Top view"):
    """x-y of every trajectory (equal axes), its start marked."""
    with figure(*SIZES_IN["trajectories_xy.png"]) as fig:
        ax = fig.add_subplot()
        for k, t in enumerate(tracks):
            p = t.positions[:: stride(len(t))]
            ax.plot(p[:, 0], p[:, 1], color=color(k), lw=1.6, label=short_label(t.name))
            ax.plot(t.positions[0, 0], t.positions[0, 1], "o", color=color(k), ms=6)
        ax.set_aspect("equal", adjustable="datalim")
        ax.set_xlabel("x [m]")
        ax.set_ylabel("y [m]")
        ax.set_title(f"{title} (dots: starts)")
        ax.legend(loc="best")
    return fig


def _stacked(size: tuple[float, float], tracks: Sequence[Trajectory], series, labels: tuple[str, ...], title: str,
             turns: bool = False):
    """Panels sharing the time axis, one per label; ``series(track)`` -> (N, panels) values or None (no line).
    ``turns``: the values are angles in degrees wrapped to [-180, 180), whose lines break where they wrap."""
    starts, time_label = time_origin(tracks)
    with figure(*size) as fig:
        axes = fig.subplots(len(labels), 1, sharex=True, squeeze=False)[:, 0]
        for k, (t, t0) in enumerate(zip(tracks, starts)):
            values = series(t)
            if values is None:
                continue
            step = stride(len(values))
            secs, values = _seconds(t, t0)[::step], values[::step]
            for i, ax in enumerate(axes):
                x, y = break_at_wraps(secs, values[:, i]) if turns else (secs, values[:, i])
                ax.plot(x, y, color=color(k), lw=1.2, label=short_label(t.name))
        for ax, label in zip(axes, labels):
            ax.set_ylabel(label)
        axes[-1].set_xlabel(time_label)
        axes[0].set_title(title)
        if any(ax.lines for ax in axes):
            axes[0].legend(loc="best")
    return fig


def xyz_figure(tracks: Sequence[Trajectory]):
    return _stacked(SIZES_IN["xyz.png"], tracks, lambda t: t.positions, ("x [m]", "y [m]", "z [m]"),
                    "Position over time")


def wrapped_degrees(rad: np.ndarray) -> np.ndarray:
    """Angles in degrees within [-180, 180)."""
    return (np.degrees(rad) + 180.0) % 360.0 - 180.0


def break_at_wraps(x: np.ndarray, deg: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(x, deg) with a NaN inserted between samples that jump more than half a turn (a wrap), so no line crosses
    the panel there."""
    at = np.flatnonzero(np.abs(np.diff(deg)) > 180.0) + 1
    return np.insert(np.asarray(x, dtype=np.float64), at, np.nan), np.insert(deg, at, np.nan)


def rpy_figure(tracks: Sequence[Trajectory]):
    return _stacked(SIZES_IN["rpy.png"], tracks,
                    lambda t: None if t.position_only else wrapped_degrees(roll_pitch_yaw(t.poses[:, :3, :3])),
                    ("roll [deg]", "pitch [deg]", "yaw [deg]"), "Orientation over time (R = Rz(yaw) Ry(pitch) Rx(roll))",
                    turns=True)


def speeds(t: Trajectory) -> tuple[np.ndarray, np.ndarray]:
    """(stamps_ns halfway between consecutive poses, |dp|/dt there in m/s), pairs with dt <= 0 left out."""
    stamps = np.asarray(t.stamps_ns, dtype=np.int64)
    dt_s = np.diff(stamps) * 1e-9
    ok = dt_s > 0
    dist = np.linalg.norm(np.diff(t.positions, axis=0), axis=1)
    mid = stamps[:-1] + np.diff(stamps) // 2
    return mid[ok], dist[ok] / dt_s[ok]


def speed_figure(tracks: Sequence[Trajectory]):
    starts, time_label = time_origin(tracks)
    with figure(*SIZES_IN["speed.png"]) as fig:
        ax = fig.add_subplot()
        for k, (t, t0) in enumerate(zip(tracks, starts)):
            mid, v = speeds(t)
            step = stride(len(v))
            ax.plot((mid[::step] - t0) * 1e-9, v[::step], color=color(k), lw=1.2, label=short_label(t.name))
        ax.set_xlabel(time_label)
        ax.set_ylabel("speed [m/s]")
        ax.set_ylim(bottom=0.0)
        ax.set_title("Speed over time (between consecutive poses)")
        if ax.lines:
            ax.legend(loc="best")
    return fig


FIGURES = {"trajectories_xy.png": top_view_figure, "xyz.png": xyz_figure, "rpy.png": rpy_figure,
           "speed.png": speed_figure}


def write_trajectory_plots(tracks: Sequence[Trajectory], folder: Path, force: bool = False) -> list[Path]:
    """Every picture of ``PLOT_FILES`` into ``folder`` (made if missing), in that order."""
    if not tracks:
        raise ValueError("no trajectory to draw")
    folder = Path(folder)
    make_folder(folder)
    return [save_png(FIGURES[name](tracks), folder / name, force) for name in PLOT_FILES]


__all__ = ["FIGURES", "PLOT_FILES", "SIZES_IN", "rpy_figure", "speed_figure", "speeds", "time_origin",
           "top_view_figure", "break_at_wraps", "wrapped_degrees", "write_trajectory_plots", "xyz_figure"]
