"""``lio evaluate``: APE/RPE (as evo computes them), KITTI segment errors and drift of estimates vs ground truth."""

from __future__ import annotations

import csv
import io
import math
import sys
import time
from pathlib import Path
from typing import Annotated, Literal, Optional

import typer
from rich.table import Table

from ...errors import ConfigError, ProcessingError
from ...evaluation import ALIGN_MODES, RELATIONS, EvalOptions, EvalResult
from ...io.files.atomic import make_folder, write_text_atomic
from ...io.sensors.sources import split_source
from ...jobs.evaluate import EvaluateJob, run_evaluate
from ...io.files.trajectory import STAMP_UNITS_NS, parse_stamp_ns
from ..common import (FLAG, INPUT_PANEL, OUTPUT_PANEL, ForceOpt, JsonOpt, LioCommand, QuietOpt, err_console, note,
                      one_of, out_console, print_json, shown, warn)
from .outputs import check_evaluate_outputs, plot_names
from .extras import csv_with_groups, parse_offset_range, parse_origin, print_group_table, resolve_groups

HELP = """Trajectory errors against ground truth: APE/RPE as evo, KITTI, drift.

APE and RPE come with rmse, mean, median, std, min, max and sse, equal to
evo's on the same settings; also KITTI odometry segment errors, the
final-position error and drift per distance travelled.

[bold]Inputs[/bold] (GT and every EST)

  gt.tum                     TUM: stamp tx ty tz qx qy qz qw, stamp in s
                             (else --gt-stamp-unit / --est-stamp-unit)
  poses.txt                  KITTI: 12 values per line, 3x4 [R|t];
                             needs --times FILE or --rate HZ
  run.bag:/ground_truth      a log topic: Odometry, PoseStamped or
                             TransformStamped ('#' works too:
                             run.bag#/ground_truth)
  run.bag                    a bare log: --gt-topic, or its only
                             ground-truth topic
  run.bag:tf:map.base_link   map -> base_link composed from /tf and
                             /tf_static (or tf:map->base_link)
  run.bag:/fix               a GPS topic (NavSatFix): positions in a
                             local east-north-up frame around the first
                             valid fix (or --origin); fixes without a
                             valid status are dropped and counted;
                             translation metrics only
  -                          standard input (TUM or KITTI), as in
                             lio odom run.bag -o - | lio evaluate gt.tum -

[bold]Steps[/bold]: pair stamps (nearest within --t-max-diff; --interpolate
resamples the denser trajectory at the other's stamps, as evo does), align
the estimate (--align, default se3; evo's default is none), then compute
APE, RPE over --delta, KITTI segments (100..800 m of ground-truth path)
and drift on the aligned estimate. --align posyaw fits translation and
yaw only (4 DoF), for estimates whose roll and pitch see gravity.

[bold]Time offset[/bold]: --estimate-offset searches the constant offset of
each estimate's clock (most stamp pairs first, then the smallest aligned
error, refined to a microsecond) within --offset-range (default: every
offset that overlaps the time ranges by half), prints it with its
precision and evaluates with it.

[bold]Runs[/bold]: --group NAME=EST,EST... (or a quoted glob, NAME='lio_*.tum')
and --group-by REGEX (the first capture group of each file name names
its group) give n, mean, std, min and max of every metric per group.

[bold]Metric names[/bold] for --fail-above and the --csv columns:
ape_REL_STAT, rpe_REL_STAT with REL = trans (m), rot (deg), rot_rad,
full (|E - I|) and STAT = rmse mean median std min max sse;
ape_rmse, rpe_rmse (translation rmse); kitti_trans_pct,
kitti_rot_deg_per_100m; final_error_m; drift_pct; matches; scale;
t_offset_s. With groups the CSV starts estimate,group,statistic.

Exit codes: 0 ok, 1 a --fail-above limit exceeded, 2 bad input.

[bold]Examples[/bold]

  lio evaluate gt.tum odom.tum
  lio evaluate run.bag:/ground_truth lio.tum kiss.tum --plot plots/
  lio evaluate gt.txt est.txt --times times.txt --delta 100 --delta-unit m
  lio evaluate gt.tum est.tum --align sim3 --json | jq .metrics[0]
  lio evaluate gt.tum est.tum --fail-above ape_rmse=0.5
  lio evaluate run.bag:/fix lio.tum --align posyaw --interpolate
  lio evaluate gt.tum est.tum --estimate-offset --offset-range -1,1
  lio evaluate gt.tum --group lio='lio_*.tum' --group kiss='kiss_*.tum'
"""

PAIRING_PANEL = "Pairing and alignment"
METRICS_PANEL = "Metrics"
Align = Literal[ALIGN_MODES]
StampUnit = Literal[tuple(STAMP_UNITS_NS)]
_DELTA_ALIASES = {"f": "frames", "frames": "frames", "frame": "frames", "m": "m", "meters": "m", "metres": "m",
                  "s": "s", "seconds": "s", "sec": "s", "d": "deg", "deg": "deg", "degrees": "deg",
                  "r": "rad", "rad": "rad", "radians": "rad"}
_CSV_HEAD = ("estimate",)


MAX_SECONDS = 1e9  # ~31 years: any larger time tolerance or offset is a typo, and overflows nanoseconds


def _parse_limits(items: list[str]) -> dict[str, float]:
    limits = {}
    for item in items:
        key, sep, value = item.partition("=")
        key = key.strip()
        if not sep or not key:
            raise ConfigError(f"--fail-above '{item}' is not METRIC=VALUE (e.g. ape_rmse=0.5)")
        try:
            limits[key] = float(value)
        except ValueError as err:
            raise ConfigError(f"--fail-above {key}: '{value}' is not a number") from err
        if not math.isfinite(limits[key]):
            raise ConfigError(f"--fail-above {key}: the limit must be a finite number, got '{value}'")
    return limits


def _known_metrics() -> set[str]:
    names = {"ape_rmse", "rpe_rmse", "kitti_trans_pct", "kitti_rot_deg_per_100m", "final_error_m", "drift_pct",
             "matches", "scale", "rpe_pairs", "kitti_segments", "path_length_m", "t_offset_s"}
    for kind in ("ape", "rpe"):
        for rel in RELATIONS:
            for stat in ("rmse", "mean", "median", "std", "min", "max", "sse"):
                names.add(f"{kind}_{rel}_{stat}")
    return names


def evaluate_cmd(
    gt: Annotated[str, typer.Argument(metavar="GT", help="Ground truth: TUM/KITTI file, LOG:/topic, LOG:tf:parent.child, or a log with --gt-topic.", show_default=False)],
    estimates: Annotated[Optional[list[str]], typer.Argument(metavar="EST...", help="One or more estimates (same forms as GT); may be left to --group.", show_default=False)] = None,
    gt_topic: Annotated[Optional[str], typer.Option("--gt-topic", help="Ground-truth topic when GT is a bare log path.", show_default=False, rich_help_panel=INPUT_PANEL)] = None,
    times: Annotated[Optional[Path], typer.Option("--times", help="KITTI times file (one stamp in s per line) for KITTI pose files.", show_default=False, rich_help_panel=INPUT_PANEL)] = None,
    rate: Annotated[Optional[float], typer.Option("--rate", help="Stamp KITTI pose files at this rate (Hz) instead of --times.", show_default=False, rich_help_panel=INPUT_PANEL)] = None,
    gt_stamp_unit: Annotated[StampUnit, typer.Option("--gt-stamp-unit", metavar=one_of(StampUnit), help="Unit of GT TUM stamps.", rich_help_panel=INPUT_PANEL)] = "s",
    est_stamp_unit: Annotated[StampUnit, typer.Option("--est-stamp-unit", metavar=one_of(StampUnit), help="Unit of estimate TUM stamps.", rich_help_panel=INPUT_PANEL)] = "s",
    origin: Annotated[Optional[str], typer.Option("--origin", metavar="LAT,LON,ALT", help=shown("ENU origin of GPS topics: deg, deg, m above the WGS84 ellipsoid.", "the reference's first valid fix"), show_default=False, rich_help_panel=INPUT_PANEL)] = None,
    group: Annotated[Optional[list[str]], typer.Option("--group", metavar="NAME=EST,...", help="Statistics over these runs (EST may be a quoted glob); repeatable.", show_default=False, rich_help_panel=INPUT_PANEL)] = None,
    group_by: Annotated[Optional[str], typer.Option("--group-by", metavar="REGEX", help="On the estimates' file names; the first capture group (or the match) names each run's group.", show_default=False, rich_help_panel=INPUT_PANEL)] = None,
    t_max_diff: Annotated[float, typer.Option("--t-max-diff", help="Largest stamp difference (s) for a pair.", rich_help_panel=PAIRING_PANEL)] = 0.01,
    t_offset: Annotated[str, typer.Option("--t-offset", help="Seconds added to estimate stamps before pairing.", rich_help_panel=PAIRING_PANEL)] = "0",
    interpolate: Annotated[bool, typer.Option("--interpolate", metavar=FLAG, help="Resample the denser trajectory at the other's stamps (linear + slerp) instead of taking the nearest pose.", rich_help_panel=PAIRING_PANEL)] = False,
    align_mode: Annotated[Align, typer.Option("--align", metavar=one_of(Align), help="Umeyama se3 or sim3 (+ scale), scale only, origin (first poses coincide), posyaw (translation + yaw).", rich_help_panel=PAIRING_PANEL)] = "se3",
    n_align: Annotated[Optional[int], typer.Option("--n-align", help="Fit se3/sim3/scale/posyaw on the first N paired poses only.", show_default=False, rich_help_panel=PAIRING_PANEL)] = None,
    estimate_offset: Annotated[bool, typer.Option("--estimate-offset", metavar=FLAG, help="Find each estimate's constant time offset (most pairs, then least aligned error) and evaluate with it.", rich_help_panel=PAIRING_PANEL)] = False,
    offset_range: Annotated[Optional[str], typer.Option("--offset-range", metavar="LO,HI", help=shown("Seconds searched by --estimate-offset.", "offsets overlapping the time ranges by half"), show_default=False, rich_help_panel=PAIRING_PANEL)] = None,
    delta: Annotated[float, typer.Option("--delta", help="RPE step.", rich_help_panel=METRICS_PANEL)] = 1.0,
    delta_unit: Annotated[str, typer.Option("--delta-unit", help="Unit of --delta: frames, m (path), s, deg or rad (accumulated rotation).", rich_help_panel=METRICS_PANEL)] = "frames",
    all_pairs: Annotated[bool, typer.Option("--all-pairs", metavar=FLAG, help="RPE over every start pose instead of consecutive windows.", rich_help_panel=METRICS_PANEL)] = False,
    pairs_from_reference: Annotated[bool, typer.Option("--pairs-from-reference", metavar=FLAG, help="Choose RPE pairs on the ground truth (default: on the aligned estimate, as evo).", rich_help_panel=METRICS_PANEL)] = False,
    delta_tol: Annotated[float, typer.Option("--delta-tol", help="Relative tolerance of --delta with --all-pairs (m, s, deg, rad).", rich_help_panel=METRICS_PANEL)] = 0.1,
    fail_above: Annotated[Optional[list[str]], typer.Option("--fail-above", metavar="METRIC=VALUE", help="Exit 1 when any estimate's metric exceeds VALUE (repeatable).", show_default=False, rich_help_panel=METRICS_PANEL)] = None,
    as_json: JsonOpt = False,
    csv_out: Annotated[Optional[str], typer.Option("--csv", metavar="FILE", help="Write one CSV row per estimate to FILE, or '-' for stdout.", show_default=False, rich_help_panel=OUTPUT_PANEL)] = None,
    plot: Annotated[Optional[Path], typer.Option("--plot", metavar="DIR", help="Write PNG plots (top view, APE over time and distance, RPE histogram) and metrics.json into DIR.", show_default=False, rich_help_panel=OUTPUT_PANEL)] = None,
    force: ForceOpt = False,
    quiet: QuietOpt = False,
) -> None:
    t_start = time.perf_counter()
    unit = _DELTA_ALIASES.get(delta_unit.lower())
    if unit is None:
        raise ConfigError(f"--delta-unit must be frames, m, s, deg or rad, got '{delta_unit}'")
    if not 0 <= t_max_diff <= MAX_SECONDS:
        raise ConfigError(f"--t-max-diff must be between 0 and {MAX_SECONDS:g} s, got {t_max_diff}")
    if n_align is not None and n_align < 1:
        raise ConfigError(f"--n-align must be at least 1 pose, got {n_align}")
    if not 0 <= delta_tol < math.inf:
        raise ConfigError(f"--delta-tol must be a finite number >= 0, got {delta_tol}")
    if not 0 < delta < math.inf:
        raise ConfigError(f"--delta must be a finite number > 0, got {delta}")
    if as_json and csv_out == "-":
        raise ConfigError("--json and --csv - would both write to stdout; give --csv a file name")
    if n_align is not None and align_mode not in ("se3", "sim3", "scale", "posyaw"):
        raise ConfigError(f"--n-align needs --align se3, sim3, scale or posyaw (not {align_mode})")
    if times is not None and rate is not None:
        raise ConfigError("give --times or --rate, not both")
    try:
        offset_ns = parse_stamp_ns(t_offset)
    except OverflowError as err:
        raise ConfigError(f"--t-offset must be within +-{MAX_SECONDS:g} s, got {t_offset}") from err
    except ValueError as err:
        raise ConfigError(f"--t-offset '{t_offset}' is not a number of seconds") from err
    if abs(offset_ns) > MAX_SECONDS * 1e9:
        raise ConfigError(f"--t-offset must be within +-{MAX_SECONDS:g} s, got {t_offset}")
    if estimate_offset and offset_ns != 0:
        raise ConfigError("give --t-offset or --estimate-offset, not both")
    if offset_range is not None and not estimate_offset:
        raise ConfigError("--offset-range needs --estimate-offset")
    range_ns = parse_offset_range(offset_range) if offset_range is not None else None
    enu_origin = parse_origin(origin) if origin is not None else None
    groups, estimates, ungrouped = resolve_groups(group or [], group_by, list(estimates or []))
    if not estimates:
        raise ConfigError("give at least one estimate (EST arguments or --group NAME=EST,...)")
    limits = _parse_limits(fail_above or [])
    unknown = sorted(set(limits) - _known_metrics())
    if unknown:
        raise ConfigError(f"--fail-above: unknown metric {', '.join(unknown)} (see lio evaluate --help for names)")
    csv_path = None if csv_out in (None, "-") else Path(csv_out)
    inputs = [Path(split_source(spec)[0]) for spec in (gt, *estimates)] + ([times] if times is not None else [])
    check_evaluate_outputs(csv_path, plot, force, inputs, plot_names(estimate_offset, bool(groups)))

    opts = EvalOptions(max_diff_ns=int(round(t_max_diff * 1e9)), offset_ns=offset_ns,
                       method="interpolate" if interpolate else "nearest", align=align_mode, n_align=n_align,
                       delta=delta, delta_unit=unit, all_pairs=all_pairs, pairs_from_reference=pairs_from_reference,
                       delta_tol=delta_tol, estimate_offset=estimate_offset, offset_range_ns=range_ns)
    job = EvaluateJob(gt, tuple(estimates), opts, t_max_diff_s=t_max_diff, gt_topic=gt_topic, times=times,
                      rate_hz=rate, gt_stamp_unit=gt_stamp_unit, est_stamp_unit=est_stamp_unit, origin=enu_origin,
                      groups=tuple(groups), ungrouped=tuple(ungrouped))
    res = run_evaluate(job)
    results, group_stats, report = res.results, res.group_stats, res.report
    report["elapsed_s"] = round(time.perf_counter() - t_start, 4)
    stdout_taken = as_json or csv_out == "-"
    for line in res.notes:
        note(line, quiet)
    for line in res.warnings:
        warn(line)
    if not quiet or not stdout_taken:
        console = err_console if stdout_taken else out_console
        _print_tables(results, opts, console)
        if group_stats is not None:
            print_group_table(group_stats, console, estimate_offset, align_mode in ("sim3", "scale"))
    if csv_out is not None:
        text = _csv_text(results) if group_stats is None else csv_with_groups(results, groups, group_stats)
        if csv_path is None:
            sys.stdout.write(text)
            sys.stdout.flush()
        else:
            write_text_atomic(csv_path, text, force)
            note(f"wrote {csv_path}", quiet)
    if plot is not None:
        from ...plots.evaluate import write_plots
        import json

        make_folder(plot)
        paths = write_plots(res.reference.positions, results, plot, force, ref_as_points=res.reference.position_only,
                            groups=group_stats)
        write_text_atomic(plot / "metrics.json", json.dumps(_jsonable(report), indent=2) + "\n", force)
        note(f"wrote {', '.join(str(p) for p in paths)} and {plot / 'metrics.json'}", quiet)
    if as_json:
        print_json(report)
    _check_limits(results, limits)


def _jsonable(obj):
    import numpy as np

    if isinstance(obj, dict):
        return {k: _jsonable(v) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return [_jsonable(v) for v in obj]
    if isinstance(obj, np.ndarray):
        return obj.tolist()
    if isinstance(obj, np.generic):
        return obj.item()
    return obj


def _csv_text(results: list[EvalResult]) -> str:
    rows = [r.flat_metrics() for r in results]
    cols = list(rows[0])
    buf = io.StringIO()
    w = csv.writer(buf, lineterminator="\n")
    w.writerow([*_CSV_HEAD, *cols])
    for r, row in zip(results, rows):
        w.writerow([r.name, *("" if row[c] is None else repr(float(row[c])) if isinstance(row[c], float) else row[c]
                              for c in cols)])
    return buf.getvalue()


def _fmt(v: float | None, digits: int = 4) -> str:
    if v is None:
        return "-"
    return f"{v:.{digits}g}" if abs(v) < 1e5 else f"{v:.3e}"


def _print_tables(results: list[EvalResult], o: EvalOptions, console) -> None:
    r0 = results[0]
    assoc = "interpolated" if o.method == "interpolate" else f"nearest within {o.max_diff_ns / 1e9:g} s"
    n_txt = f", first {r0.alignment.n_used} poses" if o.n_align else ""
    console.print(f"[bold]reference[/bold] {r0.association.ref.name}   pairing: {assoc}   "
                  f"alignment: {o.align}{n_txt}   RPE delta: {o.delta:g} {o.delta_unit}"
                  f"{' (all pairs)' if o.all_pairs else ''}")
    if any(r.options.translation_only for r in results):
        console.print("translation metrics only: positions without orientations (GPS) carry no rotation error")
    for r in results:
        if r.offset is not None:
            f = r.offset
            pm = f" +- {f.precision_s * 1e3:.2g} ms" if f.precision_s is not None else ""
            console.print(f"time offset {r.name}: {f.offset_s:+.6f} s{pm} (from {f.decided_by}; aligned rmse "
                          f"{f.rmse_m:.4g} m; searched {f.range_ns[0] / 1e9:.6g}..{f.range_ns[1] / 1e9:.6g} s)")
    if len(results) == 1:
        r = r0
        o_r = r.options
        table = Table(box=None, pad_edge=False, title=f"{r.name}  ({len(r.association.ref)} pairs"
                      f"{f', scale {r.alignment.scale:.6g}' if o.align in ('sim3', 'scale') else ''})", title_justify="left")
        table.add_column("metric")
        for stat in ("rmse", "mean", "median", "std", "min", "max"):
            table.add_column(stat, justify="right")
        rels = (("trans", "translation [m]"), ("rot", "rotation [deg]"), ("full", "full |E-I|"))
        for kind in ("ape", "rpe"):
            for rel, label in rels[:1] if o_r.translation_only else rels:
                s = r.stats[kind][rel]
                table.add_row(f"{kind.upper()} {label}", *(_fmt(s[k]) for k in ("rmse", "mean", "median", "std", "min", "max")))
        console.print(table)
        k, d = r.kitti, r.drift
        if k["segments"]:
            console.print(f"KITTI segments ({k['segments']}): translation {_fmt(k['trans_pct'])} %, "
                          f"rotation {_fmt(k['rot_deg_per_100m'])} deg/100 m")
        else:
            console.print(f"KITTI segments: none ({k['note']})")
        drift_txt = f"{_fmt(d['drift_pct'])} % of {d['path_length_m']:.1f} m" if d["drift_pct"] is not None else "-"
        console.print(f"final-position error {_fmt(d['final_error_m'])} m, drift {drift_txt}")
        return
    table = Table(box=None, pad_edge=False)
    cols = [("estimate", "left"), ("pairs", "right"), ("APE rmse m", "right"), ("APE rot deg", "right"),
            ("RPE rmse m", "right"), ("RPE rot deg", "right"), ("KITTI %", "right"), ("KITTI deg/100m", "right"),
            ("final m", "right"), ("drift %", "right")]
    for name, just in cols:
        table.add_column(name, justify=just, no_wrap=True)
    for r in results:
        m = r.flat_metrics()
        table.add_row(r.name, str(m["matches"]), _fmt(m["ape_trans_rmse"]), _fmt(m["ape_rot_rmse"]),
                      _fmt(m["rpe_trans_rmse"]), _fmt(m["rpe_rot_rmse"]), _fmt(m["kitti_trans_pct"]),
                      _fmt(m["kitti_rot_deg_per_100m"]), _fmt(m["final_error_m"]), _fmt(m["drift_pct"]))
    if not console.is_terminal:  # a pipe or file gets the whole table, not one cut to 80 columns
        from rich.console import Console

        console = Console(file=console.file, width=250, highlight=False, soft_wrap=True)
    console.print(table)


def _check_limits(results: list[EvalResult], limits: dict[str, float]) -> None:
    failures = []
    for r in results:
        m = r.flat_metrics()
        for key, limit in limits.items():
            v = m[key]
            if v is None:
                failures.append(f"{r.name}: {key} is undefined (limit {limit:g})")
            elif v > limit:
                failures.append(f"{r.name}: {key} = {v:.6g} exceeds {limit:g}")
    if failures:
        raise ProcessingError("--fail-above: " + "; ".join(failures))


def register(app: typer.Typer) -> None:
    app.command("evaluate", help=HELP, no_args_is_help=True, cls=LioCommand)(evaluate_cmd)
