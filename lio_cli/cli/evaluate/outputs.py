"""``lio evaluate``'s files (``--csv FILE``, ``--plot DIR`` with its PNGs and metrics.json), every one checked
before any work: writable, no input, and no two of them the same file."""

from __future__ import annotations

from pathlib import Path

from ...io.files.atomic import check_writable
from ...io.files.output_paths import check_plot_dir, plot_outputs, refuse_shared_outputs, refuse_stdout


def plot_names(estimate_offset: bool, groups: bool) -> tuple[str, ...]:
    """The files ``--plot DIR`` writes into DIR."""
    from ...plots.evaluate import GROUPS_PLOT, OFFSET_PLOT, PLOT_FILES

    return (*PLOT_FILES, *(OFFSET_PLOT,) * estimate_offset, *(GROUPS_PLOT,) * groups, "metrics.json")


def check_evaluate_outputs(csv_path: Path | None, plot: Path | None, force: bool, inputs: list[Path],
                           names: tuple[str, ...]) -> None:
    refuse_stdout("--plot", plot, "PNG files and metrics.json into a folder")
    named: list[tuple[str, Path]] = []
    if csv_path is not None:
        named.append(("the CSV file (--csv)", csv_path))
    refuse_shared_outputs(named + plot_outputs(plot, names))
    if csv_path is not None:
        check_writable(csv_path, force, inputs)
    if plot is not None:
        check_plot_dir(plot, names, force, inputs)


__all__ = ["check_evaluate_outputs", "plot_names"]
