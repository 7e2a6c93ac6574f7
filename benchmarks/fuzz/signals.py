"""Signals and the issue-32 cases for the fuzz harness (``--mode signals``).

A signal trial runs one command (info --check, odom, deskew, calibrate, fuse, evaluate, batch on local
processes or on a local Dask cluster; odom --map --plot --viz-save, deskew --map, plot of four sources aligned
by sim3, fuse --smooth --plot --cov of the GPS drive, calibrate of that drive, config) on an unmutated base log in its own process group and sends SIGINT or
SIGTERM to the group at a drawn moment (start-up included). The run must end within --timeout of the signal
with 130/143 and one line, or (finished first) as it would have; it fails on a traceback, an internal error, a
hang, more than one stderr line when interrupted, a partial output (a temporary file or partial folder, or an
output beside a non-zero exit), or a modified input.

The cases are the table of issue 32, each run once per harness run: concurrent batches on one root, a full
device (a 600 kB tmpfs; skipped where mounting is refused), out-of-range calibration values and integer
config fields, IMU samples of 1e300, hostile run names, and a drive shorter than the start-up window.
"""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np

import logs
from runner import _env, lio_command, tree_hash

ROOT = Path(__file__).resolve().parents[2]
MOMENTS_S = (0.1, 0.6, 1.5, 3.0, 5.0)  # after the start: interpreter start-up, imports, reading, running
SIGNALS = {"SIGINT": (signal.SIGINT, 130, "interrupted"), "SIGTERM": (signal.SIGTERM, 143, "terminated")}
COMMANDS = ("info", "odom", "deskew", "calibrate", "fuse", "evaluate", "batch", "batch-dask", "odom --map",
            "deskew --map", "plot", "fuse --smooth gps", "calibrate drive", "config")
SIGNALS_BY_CODE = {130: signal.SIGINT, 143: signal.SIGTERM}
TEMP_MARKS = (".tmp", ".partial-", ".probe", ".lio-batch.lock")


def command_argv(name: str, log: Path, log2: Path, out: Path, gps: Path) -> tuple[list[str], set[str]]:
    """(lio arguments, the files a finished run may leave in ``out``)."""
    gt = log.with_name(log.name.split(".")[0] + ".gt.tum")
    if name == "info":
        return ["info", "--check", str(log)], set()
    if name == "odom":
        return ["odom", str(log), "-o", str(out / "o.tum")], {"o.tum", "o.odom.metrics.json", "o.odom.config.yaml"}
    if name == "odom --map":
        return (["odom", str(log), "-o", str(out / "o.tum"), "--map", str(out / "m.ply"), "--plot", str(out / "p"),
                 "--viz-save", str(out / "v.rrd")],
                {"o.tum", "o.odom.metrics.json", "o.odom.config.yaml", "m.ply", "m.png", "p", "v.rrd"})
    if name == "deskew":
        return ["deskew", str(log), str(out / "d.bag")], {"d.bag", "d.deskew.metrics.json", "d.deskew.config.yaml"}
    if name == "deskew --map":
        return (["deskew", str(log), str(out / "d.bag"), "--map", str(out / "m.pcd")],
                {"d.bag", "d.deskew.metrics.json", "d.deskew.config.yaml", "m.pcd", "m.png"})
    if name in ("calibrate", "calibrate drive"):
        return (["calibrate", str(gps if name == "calibrate drive" else log), "-o", str(out / "c.yaml")],
                {"c.yaml", "c.calib.metrics.json", "c.calib.config.yaml"})
    if name == "fuse":
        return ["fuse", str(log), "-o", str(out / "f.tum")], {"f.tum", "f.fuse.metrics.json", "f.fuse.config.yaml"}
    if name == "fuse --smooth gps":
        return (["fuse", str(gps), "-o", str(out / "f.tum"), "--smooth", "--plot", str(out / "p"), "--cov",
                 str(out / "f.cov")], {"f.tum", "f.fuse.metrics.json", "f.fuse.config.yaml", "p", "f.cov"})
    if name == "plot":
        gps_gt = gps.with_name(gps.name.split(".")[0] + ".gt.tum")
        return (["plot", str(gt), f"{log}:/ground_truth", str(gps_gt), f"{gps}:/gps/fix", "--align", "sim3", "-o",
                 str(out / "p")], {"p"})
    if name == "config":
        return ["config", "fuse", "-o", str(out / "c.yaml")], {"c.yaml"}
    if name == "evaluate":
        return ["evaluate", f"{log}:/ground_truth", str(gt), "--csv", str(out / "e.csv")], {"e.csv"}
    where = ["--dask", "local", "--workers", "2"] if name == "batch-dask" else ["--jobs", "2"]
    return ["batch", "deskew", str(log), str(log2), "-O", str(out / "b"), *where], {"b"}


def run_signalled(argv: list[str], cwd: Path, delay_s: float, sig: int, timeout_s: float) -> dict:
    """Run ``lio ARGV`` in its own group, signal the group after ``delay_s``; exit, stderr, seconds to exit."""
    t0 = time.perf_counter()
    p = subprocess.Popen(lio_command(4096) + argv, cwd=cwd, env=_env(), stdout=subprocess.DEVNULL,
                         stderr=subprocess.PIPE, stdin=subprocess.DEVNULL, text=True, start_new_session=True)
    try:
        p.wait(timeout=delay_s)
        sent = False
    except subprocess.TimeoutExpired:
        os.killpg(p.pid, sig)
        sent = True
    t_sig = time.perf_counter()
    try:
        _, err = p.communicate(timeout=timeout_s)
        code = p.returncode
    except subprocess.TimeoutExpired:
        os.killpg(p.pid, signal.SIGKILL)
        _, err = p.communicate()
        code = "timeout"
    _reap_group(p.pid)
    return {"exit": code, "stderr": err, "sent": sent, "stop_s": round(time.perf_counter() - t_sig, 2),
            "wall_s": round(time.perf_counter() - t0, 2)}


def _reap_group(pgid: int) -> None:
    """Kill what the run left in its group (a worker that outlived it is itself a failure, reported as a hang)."""
    try:
        os.killpg(pgid, 0)
    except (ProcessLookupError, PermissionError):
        return
    try:
        os.killpg(pgid, signal.SIGKILL)
    except ProcessLookupError:
        pass


def classify_signalled(run: dict, out: Path, allowed: set[str], code_want: int, word: str) -> list[str]:
    err, code, cats = run["stderr"], run["exit"], []
    if "Traceback (most recent call last)" in err:
        cats.append("traceback")
    if "internal error" in err:
        cats.append("internal error")
    left0 = {p.name for p in out.iterdir()}
    if code == "timeout":
        cats.append("hang")
    elif code == -int(SIGNALS_BY_CODE[code_want]) and allowed and left0 == allowed:
        run["note"] = "killed by the signal as it exited, its outputs complete"  # Python's finalisation: SIG_DFL
        return cats
    elif run["sent"] and code not in (code_want, 0, 1, 2):
        cats.append("wrong exit")
    # what the run said before the signal (topics chosen, "N runs on ...") may precede; the stop is one line, last
    lines = [ln for ln in err.splitlines() if ln.strip()]
    said = [ln for ln in lines if ln.startswith("lio: ") and not ln.startswith("lio: warning:")]
    if code == code_want and (lines[-1:] != said or said != [f"lio: {word}; nothing half-written was left behind"]):
        cats.append("not one line")
    left = {str(p.relative_to(out)) for p in out.rglob("*")}
    if any(m in name for name in left for m in TEMP_MARKS):
        cats.append("partial output")
    elif code not in (0, 1) and not (out / "b").exists() and left:
        cats.append("partial output")  # an interrupted run leaves nothing (a batch: finished runs, checked below)
    elif code in (0, 1) and {n for n in left if "/" not in n} - allowed:
        cats.append("unexpected file")
    if (out / "b" / "summary.json").exists():
        summary = json.loads((out / "b" / "summary.json").read_text())
        ok = sorted(r["name"] for r in summary["runs"] if r["status"] in ("ok", "skipped"))
        if ok != sorted(p.name for p in (out / "b").iterdir() if p.is_dir()):
            cats.append("summary differs from folders")
    return cats


def run_signal_trial(trial: int, args, bases: dict[str, Path]) -> dict:
    rng = np.random.default_rng([args.seed, trial, 32])
    name = COMMANDS[int(rng.integers(len(COMMANDS)))] if rng.random() > 0.05 else "batch-dask"
    if name == "batch-dask" and rng.random() < 0.6:  # a local cluster is slow to start: fewer of them
        name = "batch"
    sig_name = ["SIGINT", "SIGTERM"][int(rng.integers(2))]
    delay = float(MOMENTS_S[int(rng.integers(len(MOMENTS_S)))] * rng.uniform(0.7, 1.3))
    base_names = [b for b in bases if b.startswith(("handheld", "corridor"))]
    log = bases[base_names[int(rng.integers(len(base_names)))]]
    log2 = bases["handheld_ros1"] if log != bases["handheld_ros1"] else bases["corridor_ros1"]
    tdir = args.out / "trials" / f"s{trial:04d}"
    subprocess.run(["rm", "-rf", str(tdir)], check=False)
    (tdir / "out").mkdir(parents=True)
    argv, allowed = command_argv(name, log, log2, tdir / "out", bases["drive_gps"])
    before = {p: tree_hash(p) for p in (log, log2, bases["drive_gps"])}
    sig, code_want, word = SIGNALS[sig_name]
    run = run_signalled(argv, tdir / "out", delay, sig, args.timeout)
    cats = classify_signalled(run, tdir / "out", allowed, code_want, word)
    if any(tree_hash(p) != h for p, h in before.items()):
        cats.append("modified input")
    return {"trial": trial, "kind": "signal", "command": name, "signal": sig_name, "delay_s": round(delay, 2),
            "argv": ["lio", *argv], **run, "stderr": run["stderr"][-2000:], "categories": cats}


# ---------------------------------------------------------------- the cases of issue 32

def _lio(argv: list[str], cwd: Path, timeout_s: float) -> subprocess.CompletedProcess:
    return subprocess.run(lio_command(4096) + argv, cwd=cwd, env=_env(), capture_output=True, text=True,
                          timeout=timeout_s)


def _one_line_exit(res, code: int, start: str) -> list[str]:
    lines = [ln for ln in res.stderr.splitlines() if ln.strip() and not ln.startswith("lio: warning:")]
    cats = []
    if res.returncode != code:
        cats.append(f"exit {res.returncode}, not {code}")
    if "Traceback" in res.stderr or "internal error" in res.stderr:
        cats.append("traceback")
    said = [ln for ln in lines if ln.startswith("lio: ")]  # the topics chosen etc. may precede it
    if code and (len(said) != 1 or lines[-1] != said[0] or not said[0].startswith(start)):
        cats.append("not the one line")
    return cats


def run_cases(args, bases: dict[str, Path]) -> list[dict]:
    work = args.out / "trials" / "cases"
    subprocess.run(["rm", "-rf", str(work)], check=False)
    work.mkdir(parents=True)
    log = bases["handheld_ros1"]
    t = args.timeout
    results = []

    def case(name: str, cats: list[str], stderr: str = "") -> None:
        results.append({"trial": len(results), "kind": "case", "command": name, "categories": cats,
                        "stderr": stderr[-2000:]})

    # 5: calibration values out of range; 7: integer config fields of 10^15
    for i, text in enumerate(["wheel: {speed_scale: .inf, speed_scale_sigma: 0, yaw_rate_scale: 1, "
                              "yaw_rate_scale_sigma: 0}", "imu_time_offset_sigma_s: .inf",
                              "gyro_bias_sigma_radps: [-0.1, 0, 0]", "imu_noise: {accel_noise_mps2: 1.0e+300}",
                              "T_base_imu: [[1,0,0,1.0e+300],[0,1,0,0],[0,0,1,0],[0,0,0,1]]",
                              "accel_bias_mps2: [1.0e+6, 0, 0]"]):
        (work / f"cal{i}.yaml").write_text(text + "\n")
        for cmd in ("odom", "fuse"):
            res = _lio([cmd, str(log), "-o", str(work / f"x{i}.tum"), "--calib", str(work / f"cal{i}.yaml")], work, t)
            case(f"{cmd} --calib {text[:30]}", _one_line_exit(res, 2, f"lio: error: {work / f'cal{i}.yaml'}: "),
                 res.stderr)
    for cmd, text in (("odom", "registration:\n  max_points_per_voxel: 1000000000000000\n"),
                      ("deskew", "odometry:\n  registration:\n    slow_register_every: 1000000000000000\n"),
                      ("calibrate", "registration:\n  threads: 1000000000000000\n")):
        (work / f"{cmd}.yaml").write_text(text)
        out = ["-o", str(work / "y.yaml")] if cmd == "calibrate" else [str(work / "y.bag")] if cmd == "deskew" \
            else ["-o", str(work / "y.tum")]
        res = _lio([cmd, str(log), *out, "--config", str(work / f"{cmd}.yaml")], work, t)
        case(f"{cmd} --config int 10^15", _one_line_exit(res, 2, f"lio: error: {work / f'{cmd}.yaml'}: "), res.stderr)
    # 8: run names
    for i, name in enumerate(['"a\\0b"', '"a\\nb"', "x" * 300]):
        (work / f"m{i}.yaml").write_text(f"output: mo{i}\nruns:\n  - log: {log}\n    command: odom\n    name: {name}\n")
        res = _lio(["batch", str(work / f"m{i}.yaml")], work, t)
        cats = _one_line_exit(res, 2, f"lio: error: {work / f'm{i}.yaml'}: runs[0]: name: ")
        if (work / f"mo{i}").exists():
            cats.append("output written")
        case(f"batch name {name[:12]}", cats, res.stderr)
    # 6: every IMU sample 1e300 (exit 2), some of them (dropped, counted, exit 0)
    conns, msgs = logs.decode_log(log, "ros1")
    for every in (False, True):
        bad = [list(m) for m in msgs]
        imu = [m for m in bad if m[1].endswith("Imu")]
        for k, m in enumerate(imu):
            if every or k % 7 == 0:
                m[3].linear_acceleration.x = 1e300
        path = work / f"imu_{'all' if every else 'some'}.bag"
        logs.write_log(path, "ros1", conns, bad)
        res = _lio(["fuse", str(path), "-o", str(work / f"imu_{every}.tum"), "-q"], work, t)
        cats = _one_line_exit(res, 2 if every else 0, "lio: error: the IMU has no usable sample")
        if "Warning" in res.stderr:
            cats.append("warning text")
        case(f"fuse IMU 1e300 ({'every' if every else 'every 7th'} sample)", cats, res.stderr)
    # 1: two batches on one root
    argv = ["batch", "deskew", str(log), str(bases["corridor_ros1"]), "-O", str(work / "two"), "--resume", "--jobs", "1",
            "-q"]
    first = subprocess.Popen(lio_command(4096) + argv, cwd=work, env=_env(), stderr=subprocess.PIPE, text=True,
                             start_new_session=True)
    deadline = time.monotonic() + t
    while not (work / "two" / ".lio-batch.lock").exists() and first.poll() is None and time.monotonic() < deadline:
        time.sleep(0.01)
    cats = []
    if first.poll() is None:
        os.killpg(first.pid, signal.SIGSTOP)
        try:
            second = _lio(argv, work, t)
        finally:
            os.killpg(first.pid, signal.SIGCONT)
        cats += _one_line_exit(second, 2, f"lio: error: {work / 'two'}: is in use by pid {first.pid}")
    else:
        cats.append("the first batch ended before the second could start")
    first.communicate(timeout=t)
    summary = json.loads((work / "two" / "summary.json").read_text())
    if sorted(r["name"] for r in summary["runs"] if r["status"] == "ok") != \
            sorted(p.name for p in (work / "two").iterdir() if p.is_dir()):
        cats.append("summary differs from folders")
    case("two batches on one root", cats)
    # 4: a full device
    disk = work / "disk"
    disk.mkdir()
    if subprocess.run(["mount", "-t", "tmpfs", "-o", "size=600k", "tmpfs", str(disk)], capture_output=True).returncode:
        case("full device (skipped: cannot mount a tmpfs here)", [])
    else:
        try:
            for cmd, out in (("deskew", [str(disk / "d.bag")]), ("fuse", ["-o", str(disk / "f.tum"), "--rate", "5000"])):
                res = _lio([cmd, str(log), *out], work, t)
                cats = _one_line_exit(res, 1, "lio: error: no space left on device: ")
                if list(disk.iterdir()):
                    cats.append("partial output")
                case(f"{cmd} on a full device", cats, res.stderr)
            res = _lio(["batch", "deskew", str(log), "-O", str(disk / "b"), "--jobs", "1", "-q"], work, t)
            cats = [] if res.returncode == 1 and (disk / "b" / "summary.csv").exists() else ["no summary"]
            case("batch on a full device", cats + (["traceback"] if "Traceback" in res.stderr else []), res.stderr)
        finally:
            subprocess.run(["umount", "-l", str(disk)], check=False)
    # 9: a drive off shorter than the start-up window
    sim = _lio(["simulate", "drive", str(work / "short.bag"), "--start", "accelerating", "--duration", "0.45", "-q"],
               work, t)
    res = _lio(["odom", str(work / "short.bag"), "-o", str(work / "short_odom.tum"), "-q"], work, t)
    cats = _one_line_exit(sim, 0, "") + _one_line_exit(res, 0, "")
    if not cats:
        z = np.array([float(ln.split()[3]) for ln in (work / "short_odom.tum").read_text().splitlines()])
        if np.abs(z - z[0]).max() >= 0.03:
            cats.append(f"climbs {np.abs(z - z[0]).max():.3f} m")
        if json.loads((work / "short_odom.odom.metrics.json").read_text())["start"].get("levelled_by") != "none":
            cats.append("levelled by the specific force")
    case("odom of a 0.45 s drive off", cats, res.stderr)
    return results


__all__ = ["COMMANDS", "run_cases", "run_signal_trial"]
