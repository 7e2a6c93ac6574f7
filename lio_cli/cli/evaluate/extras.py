"""``lio evaluate``'s GPS, time-offset and statistics-over-runs options: parsing, checks and printing."""

from __future__ import annotations

import csv
import io
import math

from rich.table import Table

from ...errors import ConfigError
from ...evaluation import EvalResult
from ...evaluation.groups import GROUP_STATS, Group, GroupStats, check_groups, expand_groups, groups_by_pattern, parse_group
from ...geodesy import EnuFrame, check_geodetic
from ...io.files.trajectory import parse_stamp_ns

# the metrics the group table shows (JSON and CSV carry every metric)
GROUP_TABLE_METRICS = (
    ("matches", "pairs", ""), ("ape_trans_rmse", "APE rmse", "m"), ("ape_rot_rmse", "APE rot rmse", "deg"),
    ("rpe_trans_rmse", "RPE rmse", "m"), ("rpe_rot_rmse", "RPE rot rmse", "deg"),
    ("kitti_trans_pct", "KITTI trans", "%"), ("kitti_rot_deg_per_100m", "KITTI rot", "deg/100m"),
    ("final_error_m", "final error", "m"), ("drift_pct", "drift", "%"),
)


def parse_origin(text: str) -> EnuFrame:
    """``LAT,LON,ALT`` (deg, deg, m above the WGS84 ellipsoid) as an ENU origin."""
    parts = [p.strip() for p in text.split(",")]
    try:
        lat, lon, alt = (float(p) for p in parts)
    except ValueError as err:
        raise ConfigError(f"--origin '{text}' is not LAT,LON,ALT (degrees, degrees, metres), e.g. 48.1,11.5,520") from err
    why = check_geodetic(lat, lon, alt)
    if why is not None:
        raise ConfigError(f"--origin '{text}': {why}")
    return EnuFrame(lat, lon, alt)


def parse_offset_range(text: str) -> tuple[int, int]:
    """``LO,HI`` seconds as int ns, LO < HI."""
    parts = [p.strip() for p in text.split(",")]
    try:
        if len(parts) != 2:
            raise ValueError(text)
        lo, hi = (parse_stamp_ns(p) for p in parts)
    except ValueError as err:
        raise ConfigError(f"--offset-range '{text}' is not LO,HI in seconds (e.g. -0.5,0.5)") from err
    if not lo < hi:
        raise ConfigError(f"--offset-range '{text}': LO must be below HI")
    return lo, hi


def resolve_groups(specs: list[str], pattern: str | None, estimates: list[str]) -> tuple[list[Group], list[str], list[str]]:
    """(groups, every estimate to evaluate, estimates --group-by left out); each group checked to hold two runs."""
    groups, all_est = expand_groups([parse_group(s) for s in specs], estimates)
    missed: list[str] = []
    if pattern is not None:
        by_pattern, missed = groups_by_pattern(pattern, all_est)
        taken = {g.name for g in groups}
        for g in by_pattern:
            if g.name in taken:
                raise ConfigError(f"--group-by names a group '{g.name}' that --group already defines")
        groups += by_pattern
    check_groups(groups)
    return groups, all_est, missed


def _fmt(v, digits: int = 4) -> str:
    if v is None:
        return "-"
    if isinstance(v, int):
        return str(v)
    return f"{v:.{digits}g}" if abs(v) < 1e5 else f"{v:.3e}"


def print_group_table(stats: list[GroupStats], console, with_offset: bool, with_scale: bool) -> None:
    """One row per group and metric: n, mean, std (over runs, n - 1), min, max."""
    table = Table(box=None, pad_edge=False, title="statistics over runs (std over runs, n - 1)", title_justify="left")
    for name, just in (("group", "left"), ("runs", "right"), ("metric", "left"), ("mean", "right"), ("std", "right"),
                       ("min", "right"), ("max", "right")):
        table.add_column(name, justify=just, no_wrap=True)
    rows = list(GROUP_TABLE_METRICS)
    if with_offset:
        rows.append(("t_offset_s", "time offset", "s"))
    if with_scale:
        rows.append(("scale", "scale", ""))
    for g in stats:
        first = True
        for key, label, unit in rows:
            s = g.metrics.get(key)
            if s is None or s["n"] == 0:
                continue
            table.add_row(g.name if first else "", str(len(g.runs)) if first else "",
                          f"{label} [{unit}]" if unit else label, *(_fmt(s[k]) for k in GROUP_STATS))
            first = False
    console.print(table)


def csv_with_groups(results: list[EvalResult], groups: list[Group], stats: list[GroupStats]) -> str:
    """CSV with ``estimate,group,statistic`` first: one row per run (statistic ``run``), then per group one row
    per statistic (estimate empty). A run in several groups is listed once per group; ungrouped runs have an
    empty group."""
    rows = {r.name: r.flat_metrics() for r in results}
    cols = list(next(iter(rows.values())))
    buf = io.StringIO()
    w = csv.writer(buf, lineterminator="\n")
    w.writerow(["estimate", "group", "statistic", *cols])

    def cell(v) -> str:
        if v is None or (isinstance(v, float) and not math.isfinite(v)):
            return ""
        return repr(float(v)) if isinstance(v, float) else str(v)

    grouped = {m for g in groups for m in g.members}
    for g in groups:
        for m in g.members:
            w.writerow([m, g.name, "run", *(cell(rows[m][c]) for c in cols)])
    for r in results:
        if r.name not in grouped:
            w.writerow([r.name, "", "run", *(cell(rows[r.name][c]) for c in cols)])
    for g in stats:
        for stat in GROUP_STATS:
            w.writerow(["", g.name, stat, *(cell(g.metrics[c][stat]) for c in cols)])
    return buf.getvalue()
