"""A batch's summary: one record per run (in the batch's order), statistics per group, and the two files
``summary.json`` and ``summary.csv`` in the output root, each written atomically."""

from __future__ import annotations

import csv
import io
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from .. import __version__
from ..evaluation.groups import Group, group_statistics
from ..io.files.atomic import write_text_atomic
from ..jobs.outputs import json_text
from .commands import KEY_METRICS

CSV_COLUMNS = ("name", "group", "command", "status", "exit_class", "exit_code", "reason", "time_s", "attempts",
               "worker", "log", *KEY_METRICS)
FINE = ("ok", "skipped")  # statuses of a run whose results are in its folder


@dataclass
class Summary:
    root: Path
    executor: str
    runs: list[dict[str, Any]]
    wall_s: float
    interrupted: bool = False
    groups: dict[str, dict] = field(default_factory=dict)
    written: str = field(default_factory=lambda: time.strftime("%Y-%m-%dT%H:%M:%SZ", time.gmtime()))

    @property
    def counts(self) -> dict[str, int]:
        c = {"runs": len(self.runs), "ok": 0, "skipped": 0, "failed": 0, "not-run": 0}
        for r in self.runs:
            c[r["status"]] = c.get(r["status"], 0) + 1
        return c

    @property
    def exit_code(self) -> int:
        """0: every run succeeded (or was finished before, with --resume); 1: some did not."""
        return 0 if all(r["status"] in FINE for r in self.runs) else 1

    def to_dict(self) -> dict[str, Any]:
        return {"lio": __version__, "written": self.written,
                "output": str(self.root), "executor": self.executor, "wall_s": round(self.wall_s, 3),
                "interrupted": self.interrupted, "exit_code": self.exit_code, "counts": self.counts,
                "runs": self.runs, "groups": self.groups}


def group_stats(runs: list[dict[str, Any]]) -> dict[str, dict]:
    """Per group of the manifest: its runs and mean/std/min/max of the run time and every numeric key metric
    over the runs that finished (a failed run has no metrics to count)."""
    members: dict[str, list[str]] = {}
    for r in runs:
        if r["group"] is not None and r["status"] in FINE:
            members.setdefault(r["group"], []).append(r["name"])
    metrics = {r["name"]: {k: v for k, v in r["metrics"].items() if isinstance(v, (int, float))}
               for r in runs if r["status"] in FINE}
    times = {r["name"]: r["time_s"] if r["status"] == "ok" else None for r in runs}  # a skipped run did no work
    for name in metrics:  # every run offers every key (None where undefined) so groups mixing commands work
        metrics[name] = {"time_s": times[name], **{k: metrics[name].get(k) for k in KEY_METRICS}}
    out = {}
    for g in group_statistics([Group(n, m) for n, m in members.items()], metrics):
        out[g.name] = {"runs": g.runs, "metrics": {k: v for k, v in g.metrics.items() if v["n"]}}
    return out


def csv_text(runs: list[dict[str, Any]]) -> str:
    buf = io.StringIO()
    w = csv.writer(buf, lineterminator="\n")
    w.writerow(CSV_COLUMNS)
    for r in runs:
        flat = {**r, **r["metrics"]}
        w.writerow(["" if flat.get(c) is None else flat[c] for c in CSV_COLUMNS])
    return buf.getvalue()


def write_summary(summary: Summary) -> tuple[Path, Path]:
    """``summary.json`` and ``summary.csv`` in the output root (replacing a previous batch's)."""
    summary.groups = group_stats(summary.runs)
    js, cs = summary.root / "summary.json", summary.root / "summary.csv"
    write_text_atomic(js, json_text(summary.to_dict()), force=True)
    write_text_atomic(cs, csv_text(summary.runs), force=True)
    return js, cs


__all__ = ["CSV_COLUMNS", "FINE", "Summary", "csv_text", "group_stats", "write_summary"]
