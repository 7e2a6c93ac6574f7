"""Run one fuzz trial: mutate a base log, run lio on it in subprocesses, classify every outcome."""

from __future__ import annotations

import argparse
import hashlib
import os
import re
import shutil
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np

import logs
import mutations as fm

ROOT = Path(__file__).resolve().parents[2]

# (name, scenario, format, output name, extra simulate options): every format, every time convention
BASES = [
    ("handheld_ros1", "handheld", "ros1", "handheld.bag", ["--columns", "180"]),
    ("handheld_ros2", "handheld", "ros2", "handheld_ros2", ["--columns", "180", "--time-convention", "ouster"]),
    ("handheld_mcap", "handheld", "mcap", "handheld.mcap", ["--columns", "180", "--time-convention", "livox"]),
    ("corridor_ros1", "corridor", "ros1", "corridor.bag", ["--columns", "180", "--time-convention", "hesai"]),
    ("corridor_ros2", "corridor", "ros2", "corridor_ros2", ["--columns", "180", "--header-stamp", "end"]),
    ("planar_mcap", "planar", "mcap", "planar.mcap", []),
    ("drive_gps", "drive", "ros1", "drive_gps.bag", ["--columns", "180", "--gps", "--duration", "6"]),
]
DURATION_S = "2.5"
CATEGORIES = ["traceback", "internal error", "timeout", "signal", "warning text", "leftover file",
              "modified input", "exit-2 multiline", "nan output", "slow", "high memory", "check missed"]
_WARNING = re.compile(r"\b[A-Z]\w*Warning\b|encountered in|SVD did not converge|warnings\.warn")


def simulate_bases(base_dir: Path, timeout_s: float) -> dict[str, Path]:
    base_dir.mkdir(parents=True, exist_ok=True)
    out = {}
    for name, scenario, fmt, fname, extra in BASES:
        path = base_dir / fname
        cmd = lio_command(4096) + ["simulate", scenario, str(path), "--duration", DURATION_S, "--format", fmt, "--seed", "1",
                     "--force", "-q", *extra]
        res = subprocess.run(cmd, env=_env(), capture_output=True, text=True, timeout=timeout_s)
        if res.returncode != 0:
            sys.exit(f"fuzz: cannot simulate the base log {name}: {res.stderr.strip()}")
        out[name] = path
    return out


def _env(pywarnings: str | None = None) -> dict:
    env = dict(os.environ, PYTHONPATH=str(ROOT), COLUMNS="200")
    env.pop("PYTHONWARNINGS", None)
    if pywarnings:
        env["PYTHONWARNINGS"] = pywarnings
    return env


def lio_command(max_as_mb: int) -> list[str]:
    """``lio`` from this checkout, capping its own address space (no preexec_fn: the child is not a fork of
    this process's memory, so its peak RSS is its own)."""
    code = ("from lio_cli.cli.launch import entry; import resource, sys; cap = int(sys.argv.pop(1)); "
            "resource.setrlimit(resource.RLIMIT_AS, (cap, cap)); sys.argv[0] = 'lio'; entry()")
    return [sys.executable, "-c", code, str(max_as_mb << 20)]


def vm_hwm_kb(pid: int) -> int:
    """Peak resident memory of a running process (VmHWM), 0 once it has exited."""
    try:
        with open(f"/proc/{pid}/status") as f:
            return next((int(ln.split()[1]) for ln in f if ln.startswith("VmHWM:")), 0)
    except OSError:
        return 0


def run_lio(args: list[str], cwd: Path, timeout_s: float, max_as_mb: int, pywarnings: str | None = None) -> dict:
    """Run ``lio ARGS`` in ``cwd``: exit code (or 'timeout'), stderr, wall time and peak RSS (sampled VmHWM)."""
    t0 = time.perf_counter()
    with open(cwd.parent / "stdout.txt", "wb") as fo, open(cwd.parent / "stderr.txt", "wb") as fe:
        p = subprocess.Popen(lio_command(max_as_mb) + args, cwd=cwd, env=_env(pywarnings), stdout=fo, stderr=fe,
                             stdin=subprocess.DEVNULL, start_new_session=True)
        code, peak_kb = None, 0
        while code is None:
            peak_kb = max(peak_kb, vm_hwm_kb(p.pid))
            pid, status = os.waitpid(p.pid, os.WNOHANG)
            if pid:
                code = os.waitstatus_to_exitcode(status)
            elif time.perf_counter() - t0 > timeout_s:
                os.killpg(p.pid, signal.SIGKILL)
                os.waitpid(p.pid, 0)
                code = "timeout"
            else:
                time.sleep(0.02)
        p.returncode = -1 if code == "timeout" else code  # reaped here: keep Popen from waiting again
    err = (cwd.parent / "stderr.txt").read_text(errors="replace")
    return {"exit": code, "stderr": err, "wall_s": round(time.perf_counter() - t0, 2), "peak_rss_mb": peak_kb // 1024}


def tree_hash(path: Path) -> str:
    h = hashlib.sha256()
    for p in sorted([path] if path.is_file() else path.rglob("*")):
        h.update(str(p.relative_to(path.parent)).encode())
        if p.is_file():
            h.update(p.read_bytes())
    return h.hexdigest()


def listing(folder: Path) -> set[str]:
    return {str(p.relative_to(folder)) for p in folder.rglob("*")}


def classify(run: dict, new_files: set[str], allowed: set[str], args: argparse.Namespace) -> list[str]:
    err, code, cats = run["stderr"], run["exit"], []
    if "Traceback (most recent call last)" in err:
        cats.append("traceback")
    if "internal error" in err:
        cats.append("internal error")
    if code == "timeout":
        cats.append("timeout")
    elif code not in (0, 1, 2):
        cats.append("signal")
    if _WARNING.search(err):
        cats.append("warning text")
    # exit 1 from a lost track writes the trajectory up to there on purpose (issue 8), and says where
    kept = allowed if code == 0 or (code == 1 and "the trajectory up to there is in" in err) else set()
    if new_files - kept:
        cats.append("leftover file")
    lines = [ln for ln in err.splitlines() if ln.strip() and not ln.startswith("lio: warning:")]
    if code == 2 and len(lines) > 1:
        cats.append("exit-2 multiline")
    if code != "timeout" and run["wall_s"] > args.slow_s:
        cats.append("slow")
    if run["peak_rss_mb"] > args.max_rss_mb:
        cats.append("high memory")
    return cats


_CACHE: dict[str, tuple] = {}


def make_input(trial: int, seed: int, bases: dict[str, Path], dest: Path) -> tuple[str, Path, str, bool]:
    """Mutate a base log into ``dest``: (base name, input path, description, info --check must fail)."""
    rng = np.random.default_rng([seed, trial])
    name = list(bases)[int(rng.integers(len(bases)))]
    src, fmt = bases[name], next(b[2] for b in BASES if b[0] == name)
    path = dest / src.name
    family = rng.choice(["bytes", "truncate", "fields"], p=[0.15, 0.1, 0.75])
    if family != "fields":
        (shutil.copytree if src.is_dir() else shutil.copy2)(src, path)
        return name, path, (logs.byte_flip if family == "bytes" else logs.truncate)(path, rng), False
    if name not in _CACHE:
        _CACHE[name] = logs.decode_log(src, fmt)
    case = fm.Case(*_CACHE[name], rng)
    parts = []
    for _ in range(int(rng.choice([1, 2, 3], p=[0.6, 0.3, 0.1]))):  # what applies after the previous edits
        parts.append(fm.FIELD_MUTATIONS[case.choice(fm.applicable(case))][0](case))
    desc = "; ".join(parts)
    logs.write_log(path, fmt, case.conns, case.msgs)
    return name, path, desc, case.expect_check_fail


def run_trial(trial: int, args: argparse.Namespace, bases: dict[str, Path]) -> dict:
    tdir = args.out / "trials" / f"{trial:04d}"
    shutil.rmtree(tdir, ignore_errors=True)
    (tdir / "in").mkdir(parents=True)
    (tdir / "out").mkdir()
    try:
        name, log, desc, must_fail = make_input(trial, args.seed, bases, tdir / "in")
    except Exception as err:  # noqa: BLE001 - a mutation that cannot be written is the harness's problem
        return {"trial": trial, "error": f"mutation failed: {type(err).__name__}: {err}", "runs": []}
    before, in_files = tree_hash(log), listing(tdir / "in")
    out = tdir / "out"
    plan = [("info --check", ["info", "--check", str(log)], set()),
            ("odom", ["odom", str(log), "-o", str(out / "odom.tum"), "-q"],
             {"odom.tum", "odom.metrics.json", "odom.config.yaml"})]
    runs = []
    while plan:
        label, cmd, allowed = plan.pop(0)
        seen = listing(out)
        run = run_lio(cmd, out, args.timeout, args.max_as_mb, args.pywarnings)
        cats = classify(run, listing(out) - seen, allowed, args)
        if label == "info --check" and must_fail and run["exit"] == 0:
            cats.append("check missed")
        if label == "odom" and run["exit"] == 0:
            tum = (out / "odom.tum").read_text() if (out / "odom.tum").exists() else ""
            if re.search(r"nan|inf", tum, re.I):
                cats.append("nan output")
            plan.append(("evaluate", ["evaluate", f"{log}:/ground_truth", str(out / "odom.tum"),
                                      "--csv", str(out / "eval.csv")], {"eval.csv"}))
        runs.append({"command": label, "argv": ["lio", *cmd], **run, "categories": cats})
    if tree_hash(log) != before or listing(tdir / "in") != in_files:
        runs[-1]["categories"].append("modified input")
    return {"trial": trial, "base": name, "mutation": desc, "input": str(log), "runs": runs}
