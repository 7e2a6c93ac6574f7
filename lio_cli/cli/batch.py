"""``lio batch``: one command over many logs, on local processes or a Dask cluster (flags -> manifest -> tasks ->
run_batch -> table, summary files, exit code)."""

from __future__ import annotations

from pathlib import Path
from typing import Annotated, Optional

import typer
import yaml
from rich.table import Table

from ..batch import choose_executor, expand, load_manifest, plan_batch, run_batch, shorthand
from ..batch.manifest import BATCH_COMMANDS
from ..batch.summary import Summary
from ..errors import ConfigError
from .common import (CALIBRATION_PANEL, FLAG, INPUT_PANEL, OUTPUT_PANEL, RUN_PANEL, ForceOpt, JsonOpt, LioCommand, QuietOpt,
                     err_console, note, plural, print_json, progress_bar, shown, warn)

HELP = """Run lio odom, fuse, deskew or calibrate over many logs: each run is the very job the single command runs (same
files, byte for byte), in its own folder under the output root, on all local cores or on a Dask cluster.

[bold]What to run[/bold]: a manifest (YAML: output, defaults, runs; see the README), or the shorthand
COMMAND LOG... where each LOG may be a quoted glob ('logs/*.bag'), with --gt, --set FIELD=VALUE (any field of
the command's configuration, as in its .config.yaml), --config and --calib for every run.

[bold]Where[/bold]: --jobs N local processes (default: one per core); --dask tcp://HOST:8786 an existing Dask
scheduler; --dask local --workers N a Dask cluster on this machine (pip install 'lio-cli\\[dask]'). Workers read
the logs and write the results by path: both must be on storage every worker shares.

[bold]Writes[/bold] OUT/NAME/ per run (trajectory or log, .metrics.json, .config.yaml, job.sha256), written
aside and renamed when complete, and OUT/summary.json and OUT/summary.csv: per run status, exit class, a
one-line reason, time, attempts, key metrics and ATE/RPE with a ground truth; per group mean/std/min/max.
A failing run is recorded and the others go on. Exit 0: every run succeeded; 1: some failed; 2: bad manifest
or options. --resume skips runs whose folder holds the same job's hash; Ctrl-C keeps the finished runs.

[bold]Examples[/bold]

  lio batch odom 'logs/*.bag' --gt /ground_truth -O results/
  lio batch runs.yaml --jobs 2 --resume
  lio batch fuse 'logs/*.mcap' --set estimator=planar -O fused/
  lio batch runs.yaml --dask tcp://scheduler:8786 --json > summary.json
  lio batch runs.yaml --dask local --workers 4
"""


def _options(sets: list[str]) -> dict:
    out = {}
    for item in sets:
        key, eq, value = item.partition("=")
        if not eq or not key:
            raise ConfigError(f"--set takes FIELD=VALUE (e.g. prior=constant-velocity), got '{item}'")
        try:
            out[key.strip()] = yaml.safe_load(value)
        except yaml.YAMLError as err:
            raise ConfigError(f"--set {item}: cannot read the value ({str(err).splitlines()[0]})") from err
    return out


def batch(
    what: Annotated[list[str], typer.Argument(help="MANIFEST.yaml, or COMMAND (odom, fuse, deskew, calibrate) and logs or quoted globs.", metavar="MANIFEST | COMMAND LOG...", show_default=False)],
    gt: Annotated[Optional[str], typer.Option("--gt", help="Shorthand: ground truth of every run, a topic (/ground_truth) or a file; {stem} and {dir} stand for the log's stem and folder.", show_default=False, rich_help_panel=INPUT_PANEL)] = None,
    group: Annotated[Optional[str], typer.Option("--group", help="Shorthand: a group name for every run.", show_default=False, rich_help_panel=INPUT_PANEL)] = None,
    name: Annotated[Optional[str], typer.Option("--name", help=shown("Shorthand: each run's folder name, with {stem} and {parent} (the log's folder), e.g. '{parent}_{stem}'.", "{stem}"), show_default=False, rich_help_panel=INPUT_PANEL)] = None,
    sets: Annotated[Optional[list[str]], typer.Option("--set", metavar="FIELD=VALUE", help="Shorthand: a field of the command's configuration (repeat), e.g. --set prior=constant-velocity.", show_default=False, rich_help_panel=INPUT_PANEL)] = None,
    config: Annotated[Optional[str], typer.Option("--config", help="Shorthand: the command's YAML configuration for every run.", show_default=False, rich_help_panel=INPUT_PANEL)] = None,
    calib: Annotated[Optional[str], typer.Option("--calib", help="Shorthand: a calibration YAML for every run.", show_default=False, rich_help_panel=CALIBRATION_PANEL)] = None,
    output: Annotated[Optional[Path], typer.Option("-O", "--output", help="Output root (overrides the manifest's output:).", show_default=False, rich_help_panel=OUTPUT_PANEL)] = None,
    as_json: JsonOpt = False,
    force: ForceOpt = False,
    jobs: Annotated[Optional[int], typer.Option("--jobs", "-j", help=shown("Local processes; 1 runs in this process.", "one per core"), show_default=False, rich_help_panel=RUN_PANEL)] = None,
    dask: Annotated[Optional[str], typer.Option("--dask", help="Run on Dask: a scheduler address (tcp://HOST:8786) or 'local'.", show_default=False, rich_help_panel=RUN_PANEL)] = None,
    workers: Annotated[Optional[int], typer.Option("--workers", help=shown("With --dask local: the number of workers.", "one per core"), show_default=False, rich_help_panel=RUN_PANEL)] = None,
    resume: Annotated[bool, typer.Option("--resume", metavar=FLAG, help="Skip runs whose folder holds the same job's hash; run the others.", rich_help_panel=RUN_PANEL)] = False,
    quiet: QuietOpt = False,
) -> int:
    executor = choose_executor(jobs, dask, workers)
    if what[0] in BATCH_COMMANDS:
        manifest = shorthand(what[0], what[1:], gt, group, config, calib, _options(sets or []), name)
        base, where = Path.cwd(), "lio batch"
    else:
        if len(what) > 1:
            raise ConfigError(f"lio batch takes one manifest, or a command ({', '.join(BATCH_COMMANDS)}) and logs; "
                              f"got '{what[0]}' and {len(what) - 1} more")
        given = [f for f, v in (("--gt", gt), ("--group", group), ("--set", sets), ("--config", config),
                                ("--calib", calib), ("--name", name)) if v]
        if given:
            raise ConfigError(f"{given[0]} goes with the shorthand (lio batch COMMAND LOGS...); in a manifest put it "
                              "under defaults: or a run")
        path = Path(what[0])
        manifest = load_manifest(path)
        base, where = path.absolute().parent, str(path)
    specs = expand(manifest, base, where)
    root = output if output is not None else (base / manifest.output if manifest.output else None)
    tasks = plan_batch(specs, root, resume, force)
    note(f"{plural(len(tasks), 'run')} on {executor.describe()}; results in {_shown(tasks[0].root)}/", quiet)
    with progress_bar("runs", len(tasks), quiet) as advance:
        def done(rec: dict) -> None:
            advance(1)
            if rec["status"] == "failed":
                warn(f"{rec['name']}: {rec['exit_class']}: {rec['reason']}")

        summary = run_batch(tasks, executor, done)
    if not quiet:
        _tables(summary)
    c = summary.counts
    parts = [f"{c[k]} {k}" for k in ("ok", "skipped", "failed", "not-run") if c[k]]
    note(f"{plural(c['runs'], 'run')}: {', '.join(parts)} in {summary.wall_s:.1f} s; summary in "
         f"{_shown(summary.root / 'summary.json')} and summary.csv", quiet)
    if as_json:
        print_json(summary.to_dict())
    return summary.exit_code


def _shown(path: Path | str) -> str:
    """``path`` relative to the current folder when it lies inside it (as the user would type it)."""
    try:
        return str(Path(path).relative_to(Path.cwd()))
    except ValueError:
        return str(path)


def _reason(r: dict) -> str:
    """A run's reason for the table: what went wrong first (the log's path, which the run's name stands for,
    dropped; other paths relative), its exit class after it; summary.json keeps it in full."""
    text = r["reason"].removeprefix(f"{r['log']}: ").replace(f"{Path.cwd()}/", "")
    return f"{text} ({r['exit_class']})" if r["status"] == "failed" else text


def _fmt(v, digits: int = 4) -> str:
    return "-" if v is None else f"{v:.{digits}f}" if isinstance(v, float) else str(v)


def _tables(summary: Summary) -> None:
    from rich import box

    t = Table(title="lio batch", title_justify="left", box=box.SIMPLE_HEAD, pad_edge=False)
    # the group and command columns only when they tell runs apart
    scored = any(r["metrics"]["ate_m"] is not None for r in summary.runs)
    show = {"group": any(r["group"] for r in summary.runs),
            "command": len({r["command"] for r in summary.runs}) > 1, "ATE m": scored, "RPE m": scored}
    cols = [c for c in ("run", "group", "command", "status", "time s", "scans", "ATE m", "RPE m") if show.get(c, True)]
    for col in cols:
        t.add_column(col, justify="right" if col in ("time s", "scans", "ATE m", "RPE m") else "left", no_wrap=True)
    reasons = any(r["reason"] for r in summary.runs)
    if reasons:  # folded, never cut: at 80 columns it gets what the figures leave
        t.add_column("reason", overflow="fold", ratio=1)
    for r in summary.runs:
        m = r["metrics"]
        status = {"ok": "[green]ok[/green]", "skipped": "skipped", "failed": "[red]failed[/red]"}.get(
            r["status"], r["status"])
        cells = {"run": r["name"], "group": r["group"] or "-", "command": r["command"], "status": status,
                 "time s": _fmt(r["time_s"], 1),
                 "scans": "-" if m["scans_total"] is None else f"{m['scans_used']}/{m['scans_total']}", "ATE m": _fmt(m["ate_m"]), "RPE m": _fmt(m["rpe_m"])}
        t.add_row(*(cells[c] for c in cols), *([_reason(r)] if reasons else []))
    err_console.print(t)
    if not summary.groups:
        return
    g = Table(title="groups (mean ± std, min..max over the runs that finished)", title_justify="left",
              box=box.SIMPLE_HEAD, pad_edge=False)
    for col in ("group", "runs", "ATE m", "RPE m", "real time x"):
        g.add_column(col)
    for name, gs in summary.groups.items():
        cells = []
        for key in ("ate_m", "rpe_m", "real_time_factor"):
            s = gs["metrics"].get(key)
            if s is None:
                cells.append("-")
                continue
            std = "-" if s["std"] is None else f"{s['std']:.2g}"
            cells.append(f"{s['mean']:.4g} ± {std} ({s['min']:.4g}..{s['max']:.4g})")
        g.add_row(name, str(len(gs["runs"])), *cells)
    err_console.print(g)


def register(app: typer.Typer) -> None:
    app.command("batch", help=HELP, short_help="Run a command over many logs (local processes or Dask).",
                no_args_is_help=True, cls=LioCommand)(batch)
