"""Statistics over runs: several estimates of one reference grouped, each metric summarised per group.

Groups come from ``NAME=EST[,EST...]`` specs (an EST is an estimate as given, or a glob pattern matched
against the estimates' names and file names, else against the file system) and/or from a regular expression
on the estimates' file names (``group_by``: the first capture group, or the whole match, names the group).
Every metric of ``EvalResult.flat_metrics`` gets n, mean, std (sample, n - 1), min and max over the runs
where it is defined. A group needs at least two runs.
"""

from __future__ import annotations

import glob
import math
import re
from dataclasses import dataclass
from fnmatch import fnmatchcase
from pathlib import Path

from ..errors import ConfigError, InputError

GROUP_STATS = ("mean", "std", "min", "max")
_GLOB_CHARS = set("*?[")


@dataclass
class Group:
    """A named set of estimates (their names, as evaluated), in the order given."""

    name: str
    members: list[str]


@dataclass
class GroupStats:
    """Per metric: ``{"n", "mean", "std", "min", "max"}`` over the group's runs (None where undefined)."""

    name: str
    runs: list[str]
    metrics: dict[str, dict[str, float | int | None]]

    def summary(self) -> dict:
        return {"group": self.name, "runs": list(self.runs), "n": len(self.runs), "metrics": self.metrics}


def parse_group(text: str) -> tuple[str, list[str]]:
    """(name, member patterns) of ``NAME=EST[,EST...]``."""
    name, sep, rest = text.partition("=")
    name = name.strip()
    members = [m.strip() for m in rest.split(",") if m.strip()]
    if not sep or not name or not members:
        raise ConfigError(f"--group '{text}' is not NAME=EST[,EST...] (e.g. lio=run1.tum,run2.tum or lio='lio_*.tum')")
    return name, members


def _file_name(spec: str) -> str:
    """The file name of an estimate spec, with its topic for a log topic (``run1.bag:/odom``)."""
    from ..io.sensors.sources import split_source

    path, topic = split_source(spec)
    return Path(path).name + (f":{topic}" if topic else "")


def expand_groups(specs: list[tuple[str, list[str]]], estimates: list[str]) -> tuple[list[Group], list[str]]:
    """Groups of ``NAME=EST...`` specs, and the estimates to evaluate (the given ones plus members named only
    in a group, in order of first appearance)."""
    all_est = list(estimates)
    groups: list[Group] = []
    for name, patterns in specs:
        if any(g.name == name for g in groups):
            raise ConfigError(f"--group {name}: the name is given twice")
        members: list[str] = []
        for pat in patterns:
            if _GLOB_CHARS & set(pat):
                found = [e for e in estimates if fnmatchcase(e, pat) or fnmatchcase(_file_name(e), pat)]
                found = found or sorted(glob.glob(pat))
                if not found:
                    raise ConfigError(f"--group {name}: '{pat}' matches no estimate and no file")
            else:
                found = [pat]
            for spec in found:
                if spec in members:
                    raise ConfigError(f"--group {name}: {spec} is listed twice")
                members.append(spec)
                if spec not in all_est:
                    all_est.append(spec)
        groups.append(Group(name, members))
    return groups, all_est


def groups_by_pattern(pattern: str, estimates: list[str]) -> tuple[list[Group], list[str]]:
    """Groups named by ``pattern`` (a regex searched in each estimate's file name) and the estimates it missed."""
    try:
        rx = re.compile(pattern)
    except re.error as err:
        raise ConfigError(f"--group-by '{pattern}' is not a regular expression ({err})") from err
    by_name: dict[str, list[str]] = {}
    missed = []
    for spec in estimates:
        m = rx.search(_file_name(spec))
        if m is None:
            missed.append(spec)
            continue
        key = next((g for g in m.groups() if g), None) or m.group(0)
        by_name.setdefault(key, []).append(spec)
    if not by_name:
        raise ConfigError(f"--group-by '{pattern}' matches none of the estimates' file names")
    return [Group(k, v) for k, v in by_name.items()], missed


def check_groups(groups: list[Group]) -> None:
    """Every group needs two runs or more: one run has no spread."""
    for g in groups:
        if len(g.members) < 2:
            raise InputError(f"group '{g.name}' has one run ({g.members[0]}); statistics over runs need at least two")


def _stats(values: list[float]) -> dict[str, float | int | None]:
    n = len(values)
    if n == 0:
        return {"n": 0, **dict.fromkeys(GROUP_STATS)}
    d = [v - values[0] for v in values]  # shifted data: equal runs give a std of exactly 0
    mean = values[0] + math.fsum(d) / n
    std = math.sqrt(max(math.fsum(x * x for x in d) - math.fsum(d) ** 2 / n, 0.0) / (n - 1)) if n > 1 else None
    return {"n": n, "mean": mean, "std": std, "min": min(values), "max": max(values)}


def group_statistics(groups: list[Group], metrics: dict[str, dict[str, float | int | None]]) -> list[GroupStats]:
    """Statistics per group of every metric in ``metrics`` (estimate name -> flat metrics)."""
    out = []
    for g in groups:
        rows = [metrics[m] for m in g.members]
        keys = list(rows[0])
        table = {}
        for key in keys:
            vals = [float(r[key]) for r in rows if r.get(key) is not None and math.isfinite(float(r[key]))]
            table[key] = _stats(vals)
        out.append(GroupStats(g.name, list(g.members), table))
    return out
