"""What lio's pictures share: a matplotlib ``Figure`` of a fixed size (no pyplot state, so nothing to close and a
PNG of exactly ``size_in * DPI`` pixels), its lettering, its colours, and atomic PNG writes; ``pyplot`` and
``save_tight`` for the evaluate and fuse pictures, which are laid out by pyplot and cropped to their content."""

from __future__ import annotations

from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path

from ..io.files.atomic import atomic_output

DPI = 100
COLORS = ("#1f77b4", "#d62728", "#2ca02c", "#ff7f0e", "#9467bd", "#8c564b", "#e377c2", "#17becf")
MAX_POINTS = 20_000  # per line: plenty for a PNG, bounded for hour-long runs
_RC = {"font.size": 11, "axes.titlesize": 13, "axes.labelsize": 11, "legend.fontsize": 10, "axes.grid": True,
       "grid.alpha": 0.3}


@contextmanager
def figure(width_in: float, height_in: float) -> Iterator:
    """A ``matplotlib.figure.Figure`` of this size, drawn with lio's lettering (laid out on leaving)."""
    import matplotlib

    matplotlib.use("Agg")
    from matplotlib.figure import Figure

    with matplotlib.rc_context(_RC):
        fig = Figure(figsize=(width_in, height_in), dpi=DPI, layout="constrained")
        yield fig


def color(k: int) -> str:
    return COLORS[k % len(COLORS)]


def short_label(name: str, width: int = 40) -> str:
    return name if len(name) <= width else "..." + name[-(width - 3):]


def stride(n: int, limit: int = MAX_POINTS) -> int:
    """Every how many-th of ``n`` samples to draw so at most about ``limit`` are."""
    return max(1, -(-n // limit))


def save_png(fig, path: Path, force: bool = False) -> Path:
    """``fig`` as a PNG at ``path`` (atomically; an existing file only with ``force``)."""
    with atomic_output(Path(path), force) as tmp:
        fig.savefig(tmp, format="png", dpi=DPI)
    return Path(path)


TIGHT_DPI = 110  # the pyplot-based pictures: cropped to their content, so their size follows what they hold
_PYPLOT_RC = {"font.size": 12, "axes.titlesize": 14, "axes.labelsize": 12, "legend.fontsize": 11, "axes.grid": True,
              "grid.alpha": 0.3}


def pyplot():
    """matplotlib.pyplot on the Agg backend, lettered for the pyplot-based pictures."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    plt.rcParams.update(_PYPLOT_RC)
    return plt


def save_tight(fig, path: Path, force: bool = False) -> Path:
    """``fig`` (a pyplot figure, closed here) as a PNG cropped to its content at ``path`` (atomically; an existing
    file only with ``force``)."""
    import matplotlib.pyplot as plt

    try:
        with atomic_output(Path(path), force) as tmp:
            fig.savefig(tmp, format="png", dpi=TIGHT_DPI, bbox_inches="tight")
    finally:
        plt.close(fig)
    return path
