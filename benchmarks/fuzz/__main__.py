"""Fuzz lio's commands with mutated logs and classify what they do.

Six small logs are simulated once per run (``lio simulate``, 2.5 s each: handheld, corridor and planar over
all three formats and every per-point time convention), then every trial mutates one of them (byte flips, a
truncation, or 1-3 field edits re-serialised into a valid log, see ``mutations.py``) and runs
``lio info --check``, ``lio odom`` and, when odom wrote a trajectory, ``lio evaluate LOG:/ground_truth`` on
it, each as a subprocess with a timeout and a memory cap. A run fails when it shows a traceback, an internal
error, a timeout, a signal, numpy/Python warning text on stderr, a leftover or unexpected file, a modified
input, more than one line on stderr with exit 2 (warnings aside), NaN in a written trajectory, or costs more
than --slow-s seconds or --max-rss-mb of memory; ``info --check`` passing a log with a value it must report
(a hostile sensor stamp, a non-finite or absurd IMU sample or wheel speed, a finite but absurd point
time) is counted as ``check missed``. Trials are deterministic per seed (trial i only depends on --seed and i).
Part of the trials aim at this round's features instead (``features.py``, --targets): ``lio plot`` on hostile
trajectory files, ``odom --map --plot --viz-save`` and ``deskew --map``, ``calibrate`` on a 6 s drive with GPS,
``fuse`` (``--smooth``, every estimator) on mutated NavSatFix messages, and ``lio config``.

    python benchmarks/fuzz --trials 300 --seed 0 --jobs 2 --out /tmp/lio-fuzz

prints a summary table, writes OUT/report.json (every failing trial: its mutation and the commands to
reproduce it) and keeps each failing trial's input under OUT/trials/NNNN/ (passing ones are deleted).

    python benchmarks/fuzz --mode signals --trials 150 --jobs 1

instead sends SIGINT or SIGTERM to every command's process group at drawn moments (``signals.py``: tracebacks,
hangs, partial outputs, modified inputs) and runs the cases of issue 32 once.
"""

from __future__ import annotations

import argparse
import json
import re
import shutil
import sys
import time
from collections import Counter
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path

sys.path[:0] = [str(Path(__file__).resolve().parents[2])]  # the checkout this harness lives in

from features import TARGETS, run_any_trial  # noqa: E402
from runner import CATEGORIES, simulate_bases  # noqa: E402
from signals import COMMANDS, run_cases, run_signal_trial  # noqa: E402


def summarise(results: list[dict]) -> tuple[str, str]:
    order = ["info --check", "odom", "evaluate", "odom --map", "deskew --map", "plot", "calibrate", "fuse", "config"]
    seen = {run["command"] for r in results for run in r["runs"]}
    cmds = [c for c in order if c in seen] + sorted(seen - set(order))
    rows = {c: Counter() for c in cmds}
    for r in results:
        for run in r["runs"]:
            k = rows[run["command"]]
            k["runs"] += 1
            k[f"exit {run['exit']}" if run["exit"] in (0, 1, 2) else "exit other"] += 1
            k.update(set(run["categories"]))
    head = ["outcome", *cmds, "total"]
    lines = ["| " + " | ".join(head) + " |", "|" + "---|" * len(head)]
    for key in ["runs", "exit 0", "exit 1", "exit 2", "exit other", *CATEGORIES]:
        vals = [rows[c][key] for c in cmds]
        lines.append(f"| {key} | " + " | ".join(map(str, vals)) + f" | {sum(vals)} |")
    for key, label in (("wall_s", "longest run s"), ("peak_rss_mb", "largest peak RSS MB")):
        vals = [max((run[key] for r in results for run in r["runs"] if run["command"] == c), default=0) for c in cmds]
        lines.append(f"| {label} | " + " | ".join(f"{v:g}" for v in vals) + f" | {max(vals):g} |")
    by_family: dict[str, Counter] = {}
    for r in results:
        for part in r.get("mutation", "harness error").split("; "):
            fam = _family(part)
            c = by_family.setdefault(fam, Counter())
            c["trials"] += 1
            cats = {cat for run in r["runs"] for cat in run["categories"]}
            c["failing"] += bool(cats)
            c.update(cats)
    fam_lines = ["| mutation | trials | failing | what failed |", "|---|---|---|---|"]
    for fam, c in sorted(by_family.items()):
        what = ", ".join(f"{k} {v}" for k, v in c.most_common() if k not in ("trials", "failing"))
        fam_lines.append(f"| {fam} | {c['trials']} | {c['failing']} | {what or '-'} |")
    return "\n".join(lines), "\n".join(fam_lines)


def _family(desc: str) -> str:
    for key in ("bytes flipped", "truncated", "header stamp", "record time", "samples dropped", "PointField",
                "per-point", "xyz", "/tf_static", "scan message", "frame_id", "wheel odometry", "ground truth",
                "IMU", "GPS", "trajectory", "config", "unmutated", "dropped", "twice", "swapped", "cloud message"):
        if key in desc:
            return {"cloud message": "cloud layout", "twice": "structure", "swapped": "structure",
                    "dropped": "structure"}.get(key, key)
    return desc.split(":")[0]


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--trials", type=int, default=300)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--jobs", type=int, default=2)
    ap.add_argument("--out", type=Path, default=Path("/tmp/lio-fuzz"), help="work and report folder (emptied)")
    ap.add_argument("--only", type=int, nargs="*", help="run only these trial numbers (to reproduce)")
    ap.add_argument("--timeout", type=float, default=30.0, help="seconds per lio run")
    ap.add_argument("--slow-s", type=float, default=10.0, help="a run longer than this is 'slow'")
    ap.add_argument("--max-rss-mb", type=int, default=500, help="peak RSS above this is 'high memory'")
    ap.add_argument("--max-as-mb", type=int, default=3072, help="address-space cap of each lio run (RLIMIT_AS)")
    ap.add_argument("--pywarnings", help="PYTHONWARNINGS for the lio runs (e.g. 'default' shows ResourceWarning); "
                    "unset by default, as a user runs lio")
    ap.add_argument("--targets", nargs="+", choices=list(TARGETS), default=list(TARGETS),
                    help="what trials aim at: log (info/odom/evaluate), plot, map (odom/deskew --map), calibrate, "
                    "gps (fuse on mutated NavSatFix), config")
    ap.add_argument("--keep-all", action="store_true", help="keep passing trials' folders too")
    ap.add_argument("--mode", choices=["mutations", "signals"], default="mutations",
                    help="mutated logs (default), or signals to every command plus the issue-32 cases")
    args = ap.parse_args()
    args.out = args.out.resolve()
    shutil.rmtree(args.out / "trials", ignore_errors=True)
    t0 = time.perf_counter()
    bases = simulate_bases(args.out / "base", args.timeout)
    if args.mode == "signals":
        return signals_main(args, bases, t0)
    trials = args.only if args.only else list(range(args.trials))
    with ProcessPoolExecutor(max_workers=args.jobs) as pool:
        results = list(pool.map(run_any_trial, trials, [args] * len(trials), [bases] * len(trials)))
    failing = [r for r in results if r.get("error") or any(run["categories"] for run in r["runs"])]
    for r in results:
        if r not in failing and not args.keep_all:
            shutil.rmtree(args.out / "trials" / f"{r['trial']:04d}", ignore_errors=True)
    table, families = summarise(results)
    wall = time.perf_counter() - t0
    report = {"seed": args.seed, "trials": len(trials), "wall_s": round(wall, 1), "failing_trials": len(failing),
              "summary": table, "by_mutation": families,
              "failures": [{**r, "runs": [{**run, "command": " ".join(_q(a) for a in run["argv"]),
                                          "stderr": run["stderr"][-2000:]} for run in r["runs"]]}
                           for r in failing]}
    (args.out / "report.json").write_text(json.dumps(report, indent=2) + "\n")
    print(f"{len(trials)} trials (seed {args.seed}, {args.jobs} jobs) in {wall:.0f} s; "
          f"{len(failing)} failing, kept in {args.out / 'trials'}; report {args.out / 'report.json'}\n")
    print(table + "\n\n" + families)
    return 1 if failing else 0


def signals_main(args: argparse.Namespace, bases: dict, t0: float) -> int:
    trials = args.only if args.only else list(range(args.trials))
    with ProcessPoolExecutor(max_workers=args.jobs) as pool:
        results = list(pool.map(run_signal_trial, trials, [args] * len(trials), [bases] * len(trials)))
    cases = run_cases(args, bases)
    rows = {c: Counter() for c in COMMANDS}
    for r in results:
        k = rows[r["command"]]
        k["runs"] += 1
        k["signalled" if r["sent"] else "ended first"] += 1
        k[f"exit {r['exit']}"] += 1
        k["killed as it exited"] += bool(r.get("note"))
        k.update(set(r["categories"]))
    keys = ["runs", "signalled", "ended first", "exit 130", "exit 143", "exit 0", "exit 1", "exit 2",
            "killed as it exited", "traceback",
            "internal error", "hang", "wrong exit", "not one line", "partial output", "unexpected file",
            "summary differs from folders", "modified input"]
    lines = ["| outcome | " + " | ".join(COMMANDS) + " | total |", "|" + "---|" * (len(COMMANDS) + 2)]
    for key in keys:
        vals = [rows[c][key] for c in COMMANDS]
        lines.append(f"| {key} | " + " | ".join(map(str, vals)) + f" | {sum(vals)} |")
    stops = [r["stop_s"] for r in results if r["sent"] and r["exit"] != "timeout"]
    lines.append(f"| longest stop s | {max(stops, default=0):g} (from the signal to the exit) |")
    case_lines = ["| case | outcome |", "|---|---|"] + [
        f"| {c['command']} | {', '.join(c['categories']) or 'as expected'} |" for c in cases]
    failing = [r for r in results + cases if r["categories"]]
    wall = time.perf_counter() - t0
    (args.out / "report.json").write_text(json.dumps(
        {"mode": "signals", "seed": args.seed, "trials": len(trials), "wall_s": round(wall, 1),
         "failing": len(failing), "summary": "\n".join(lines), "cases": "\n".join(case_lines),
         "failures": failing}, indent=2) + "\n")
    print(f"{len(trials)} signal trials (seed {args.seed}, {args.jobs} jobs) and {len(cases)} cases in {wall:.0f} s; "
          f"{len(failing)} failing; report {args.out / 'report.json'}\n")
    print("\n".join(lines) + "\n\n" + "\n".join(case_lines))
    return 1 if failing else 0


def _q(arg: str) -> str:
    return arg if re.fullmatch(r"[\w./:=@+-]+", arg) else "'" + arg.replace("'", "'\\''") + "'"


if __name__ == "__main__":
    sys.exit(main())
