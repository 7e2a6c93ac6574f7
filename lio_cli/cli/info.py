"""``lio info``: what a log holds."""

from __future__ import annotations

import time
from typing import Annotated

import typer
from rich.table import Table

from ..io.messages.pointcloud import parse_time_convention
from ..io.logs.reader import open_log
from ..jobs.info import check_log, describe_log
from .common import (FLAG, RUN_PANEL, FormatOpt, JsonOpt, LioCommand, LogArg, PointTimeOpt, QuietOpt, err_console,
                     out_console, plural, print_json, progress_bar, warn)

HELP = """Show what a log holds: format, time span, topics with types, counts and rates; for every scan topic
its fields, point count and per-point time convention (and whether the header stamp marks the scan's start
or end); frames and extrinsics on /tf_static.

It reads only the log's index, the first scan of each LiDAR topic and /tf_static, so it is quick on
long logs. --check decodes every sensor message and fails (exit 2) on the first bad one.

[bold]Examples[/bold]

  lio info sample_logs/handheld.bag

  lio info run_2024_05_01/ --json | jq '.topics[].topic'

  lio info drive.mcap --check --point-time ouster
"""


def info(
    log: LogArg,
    fmt: FormatOpt = None,
    point_time: PointTimeOpt = None,
    as_json: JsonOpt = False,
    check: Annotated[bool, typer.Option("--check", metavar=FLAG, help="Decode every sensor message: stamps in order, clouds non-empty, no NaN IMU samples.", rich_help_panel=RUN_PANEL)] = False,
    quiet: QuietOpt = False,
) -> None:
    conv = parse_time_convention(point_time) if point_time else None
    t0 = time.perf_counter()
    with open_log(log, fmt) as reader:
        summary = describe_log(reader, conv)
        if check:
            total = sum(t.count for t in reader.topics.values())
            with progress_bar("checking", total, quiet) as advance:
                summary["check"] = check_log(reader, conv, advance)
    summary["elapsed_s"] = round(time.perf_counter() - t0, 4)
    if as_json:
        print_json(summary)
        return
    _print_human(summary, quiet)


def _print_human(s: dict, quiet: bool = False) -> None:
    c = out_console
    c.print(f"[bold]{s['path']}[/bold]  ({s['format']})")
    if s["messages"]:
        for what in ("start", "end"):
            ns, date = s[f"{what}_ns"], s[f"{what}_utc"]
            shown = "" if date is None else "   " + date.replace("T", " ").replace("Z", " UTC")
            c.print(f"{what:<8} {ns // 10**9}.{ns % 10**9 // 10**6:03d} s{shown}")
        c.print(f"duration {s['duration_s']:.3f} s   {plural(s['messages'], 'message')}")
    else:
        c.print("empty log: no messages")
    table = Table(box=None, pad_edge=False)
    for col, just in (("topic", "left"), ("type", "left"), ("count", "right"), ("rate Hz", "right")):
        table.add_column(col, justify=just)
    for t in s["topics"]:
        table.add_row(t["topic"], t["type"], str(t["count"]), f"{t['rate_hz']:.2f}" if t["rate_hz"] else "-")
    c.print(table)
    for sc in s["scans"]:
        c.print(f"\n[bold]{sc['topic']}[/bold] ({sc['type'].split('/')[-1]}, frame '{sc.get('frame_id', '?')}')")
        if "fields" in sc:
            fields = ", ".join(f"{f['name']}:{f['type']}" + (f"x{f['count']}" if f["count"] > 1 else "") for f in sc["fields"])
            c.print(f"  fields      {fields}  (point_step {sc['point_step']}, {sc['height']}x{sc['width']}"
                    f"{', big-endian' if sc['big_endian'] else ''})")
        elif "beams" in sc:
            c.print(f"  beams       {sc['beams']}")
        if "points" in sc:
            c.print(f"  points      {sc['valid_points']} valid of {sc['points']} in the first scan")
            tc = sc["time_convention"]
            dur = f", scan spans {tc['scan_duration_s'] * 1e3:.1f} ms" if "scan_duration_s" in tc else ""
            c.print(f"  point time  {tc['description']}; header stamp marks the scan's {tc['header_stamp_marks']}{dur}")
    if s["static_transforms"]:
        c.print("\n[bold]/tf_static[/bold]")
        for f in s["static_transforms"]:
            xyz = ", ".join(f"{v:.3f}" for v in f["xyz_m"])
            q = ", ".join(f"{v:.4f}" for v in f["quat_xyzw"])
            c.print(f"  {f['parent']} -> {f['child']}: xyz [{xyz}] m, quat_xyzw [{q}] ({f['angle_deg']:.2f} deg)")
    for problem in s.get("static_transform_problems", []):
        warn(problem)
    if "check" in s and not quiet:
        n = sum(s["check"]["checked"].values())
        err_console.print(f"check passed: {plural(n, 'sensor message')} decoded, stamps in order, clouds non-empty")


def register(app: typer.Typer) -> None:
    app.command("info", help=HELP, short_help="What a log holds: topics, rates, cloud fields, per-point time, frames.", no_args_is_help=True, cls=LioCommand)(info)
