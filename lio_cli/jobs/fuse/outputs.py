"""The files of a fuse run: the TUM trajectory with ``NAME.fuse.metrics.json`` and ``NAME.fuse.config.yaml``
beside it, the
per-pose covariance (``--cov``) and the plots (``--plot DIR``). Every location is checked before the work
starts; each file is written atomically."""

from __future__ import annotations

from collections.abc import Iterable
from pathlib import Path

import numpy as np

from ...core.fuse import COVARIANCE_LAYOUT
from ...errors import InputError
from ...io.files.atomic import atomic_output, check_writable, make_folder
from ...io.files.output_paths import check_plot_dir, plot_outputs, refuse_shared_outputs, refuse_stdout
from ...io.files.trajectory import format_stamp, format_tum
from ...plots.fuse import PLOT_FILES, write_plots
from .job import FuseRun
from ..outputs import check_outputs, run_outputs, write_run

TAG = "fuse"  # in the name of every file a run writes beside its trajectory

COV_HEADER = ("# lio fuse per-pose covariance: stamp_s, then the 6x6 matrix row-major (36 values) over "
              f"({' '.join(COVARIANCE_LAYOUT)}): position error in world axes (m^2), rotation error about the base "
              "axes (rad^2, right perturbation)\n")


def check_fuse_outputs(out: Path | None, force: bool, inputs: Iterable[Path], cov: Path | None = None,
                       plot: Path | None = None) -> None:
    """Every file the run will write may be written, is no input and no other output (before any work)."""
    refuse_stdout("--cov", cov, "the covariance to a file")
    refuse_stdout("--plot", plot, "PNG files into a folder")
    named: list[tuple[str, Path]] = []
    if out is not None:
        traj, metrics, config = run_outputs(out, TAG)
        named += [("the trajectory (-o)", traj), (f"the metrics file written beside -o {out}", metrics),
                  (f"the config file written beside -o {out}", config)]
    if cov is not None:
        named.append(("the covariance file (--cov)", cov))
    refuse_shared_outputs(named + plot_outputs(plot, PLOT_FILES, "plot"))
    inputs = list(inputs)
    if out is not None:
        check_outputs(out, TAG, force, inputs)
    if cov is not None:
        check_writable(cov, force, inputs)
    if plot is not None:
        check_plot_dir(plot, PLOT_FILES, force, inputs)


def format_covariances(stamps_ns: np.ndarray, cov: np.ndarray) -> str:
    rows = np.asarray(cov, dtype=np.float64).reshape(-1, 36)
    return COV_HEADER + "".join(f"{format_stamp(s)} " + " ".join(f"{v:.9e}" for v in r) + "\n"
                                for s, r in zip(np.asarray(stamps_ns, np.int64), rows))


def write_covariances(run: FuseRun, path: Path, force: bool) -> None:
    if run.covariances is None:
        raise InputError("no covariance was computed (the job was run without covariance=True)")
    with atomic_output(path, force) as tmp:
        tmp.write_text(format_covariances(run.trajectory.stamps_ns, run.covariances))


def write_fuse(run: FuseRun, out: Path | None, force: bool, cov: Path | None = None,
               plot: Path | None = None) -> list[Path]:
    """Write the run's files (``out`` None: no trajectory, metrics or config file, e.g. for ``-o -``); return
    them, the trajectory's first."""
    written: list[Path] = []
    if cov is not None:
        write_covariances(run, cov, force)
        written.append(cov)
        run.metrics["covariance_file"] = str(cov)
    if plot is not None:
        make_folder(plot)
        written += write_plots(run, plot, force)
        run.metrics["plots"] = [str(p) for p in written[-len(PLOT_FILES):]]
    if out is not None:
        run.metrics["output"]["file"] = str(out)
        written[:0] = write_run(out, TAG, format_tum(run.trajectory.stamps_ns, run.trajectory.poses), run.config,
                                run.metrics, force)
    return written


__all__ = ["COV_HEADER", "PLOT_FILES", "TAG", "check_fuse_outputs", "format_covariances", "write_covariances", "write_fuse"]
