"""Issue 10, as a specification: nothing lost, nothing hangs, every bad input answered.

One test per defect found by fuzzing (``benchmarks/fuzz``) and by the real recordings in
``../shared/real_logs``. Each docstring states the behaviour the test requires. Tests go through the CLI
(``lio_cli.cli.app.main`` in-process, or a subprocess where a signal, a hang, a crash or memory is at
stake); hostile logs are rewritten from small simulated ones with rosbags and lio's ``LogWriter``.
"""

from __future__ import annotations

import copy
import hashlib
import json
import math
import os
import pty
import re
import select
import shutil
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

from lio_cli.cli.app import main
from lio_cli.geometry import pose_to_xyz_quat
from lio_cli.io.logs.writer import LogWriter

REPO = Path(__file__).resolve().parents[1]



S_NS = 1_000_000_000
LIDAR, IMU, WHEEL = "/points", "/imu", "/wheel/odom"
MAX_RSS_MB = 1024  # 'bounded memory': below this whatever the stamps say ...
RSS_MARGIN_MB = 200  # ... and within this of the same log without the hostile stamp
MAX_WALL_S = 60.0
EARLY_FRACTION = 0.25  # a refused output costs less than this fraction of the run it would have ended
WARNING_TEXT = re.compile(r"\b[A-Z]\w*Warning\b|encountered in|SVD did not converge")


# ---------------------------------------------------------------- helpers

def lio(capsys, *args) -> tuple[int, str, str]:
    """Run ``lio ARGS`` in-process: (exit code, stdout, stderr)."""
    rc = main([str(a) for a in args])
    out = capsys.readouterr()
    return rc, out.out, out.err


def lio_command(max_as_mb: int = 3072) -> list[str]:
    """``lio`` from this checkout as a process that caps its own address space (so a runaway allocation fails
    instead of swapping the machine; no preexec_fn, so the child is not a copy of pytest's memory)."""
    code = ("import resource, sys; cap = int(sys.argv.pop(1)); resource.setrlimit(resource.RLIMIT_AS, (cap, cap)); "
            "sys.argv[0] = 'lio'; from lio_cli.cli.app import entry; entry()")
    return [sys.executable, "-c", code, str(max_as_mb << 20)]


def vm_hwm_kb(pid: int) -> int:
    """Peak resident memory of a running process (VmHWM), 0 once it has exited."""
    try:
        with open(f"/proc/{pid}/status") as f:
            return next((int(ln.split()[1]) for ln in f if ln.startswith("VmHWM:")), 0)
    except OSError:
        return 0


def lio_subprocess(args, cwd: Path, timeout_s: float = MAX_WALL_S) -> dict:
    """Run ``lio ARGS`` as a process: exit code (None on timeout), stderr, wall time, peak RSS (sampled VmHWM)."""
    t0 = time.perf_counter()
    with open(cwd / ".stderr", "wb") as fe:
        p = subprocess.Popen(lio_command() + [str(a) for a in args], cwd=cwd, env=_env(), stdin=subprocess.DEVNULL,
                             stdout=subprocess.DEVNULL, stderr=fe)
        peak_kb = 0
        while p.poll() is None and time.perf_counter() - t0 < timeout_s:
            peak_kb = max(peak_kb, vm_hwm_kb(p.pid))
            time.sleep(0.02)
        code = p.poll()
        if code is None:
            p.kill()
            p.wait()
    err = (cwd / ".stderr").read_text(errors="replace")
    (cwd / ".stderr").unlink()
    return {"exit": code, "stderr": err, "wall_s": time.perf_counter() - t0, "peak_rss_mb": peak_kb / 1024}


def _env() -> dict:
    env = dict(os.environ, PYTHONPATH=str(REPO), COLUMNS="200", TERM="xterm")
    env.pop("PYTHONWARNINGS", None)
    return env


def tree_hash(path: Path) -> str:
    """Content and names of a file or a folder (symlinks followed), to prove an input was not touched."""
    h = hashlib.sha256()
    for p in sorted([path] if not path.is_dir() else path.rglob("*")):
        h.update(str(p.relative_to(path.parent)).encode())
        if p.is_file():
            h.update(p.read_bytes())
    return h.hexdigest()


def listing(folder: Path) -> set[str]:
    return {str(p.relative_to(folder)) for p in folder.rglob("*")}


def one_line(err: str) -> str:
    lines = [ln for ln in err.splitlines() if ln.strip()]
    assert len(lines) == 1, f"expected one line on stderr, got {len(lines)}:\n{err}"
    return lines[0]


def rewrite(src: Path, dst: Path, edit=None) -> Path:
    """Copy the ROS 1 log ``src`` to ``dst``; ``edit(topic, index_in_topic, msg)`` returns the message to write
    (edited in place or new) or None to drop it."""
    from rosbags.highlevel import AnyReader

    seen: dict[str, int] = {}
    with AnyReader([src]) as r, LogWriter(dst, "ros1") as w:
        for c in r.connections:
            w.add_topic(c.topic, c.msgtype, latching=bool(getattr(c.ext, "latching", 0)))
        for c, t_ns, raw in r.messages():
            msg = r.deserialize(raw, c.msgtype)
            i = seen.get(c.topic, 0)
            seen[c.topic] = i + 1
            out = msg if edit is None else edit(c.topic, i, msg)
            if out is not None:
                w.write(c.topic, t_ns, out)
    return dst


def set_stamp(msg, ns: int) -> None:
    msg.header.stamp.sec, msg.header.stamp.nanosec = int(ns // S_NS), int(ns % S_NS)


def stamp_ns(msg) -> int:
    return int(msg.header.stamp.sec) * S_NS + int(msg.header.stamp.nanosec)


_NP = {1: "i1", 2: "u1", 3: "i2", 4: "u2", 5: "i4", 6: "u4", 7: "f4", 8: "f8"}


def cloud_array(msg) -> np.ndarray:
    dt = np.dtype({"names": [f.name for f in msg.fields], "offsets": [f.offset for f in msg.fields],
                   "formats": ["<" + _NP[f.datatype] for f in msg.fields], "itemsize": msg.point_step})
    return np.frombuffer(np.asarray(msg.data, dtype=np.uint8).tobytes(), dtype=dt).copy()


def set_cloud_array(msg, arr: np.ndarray) -> None:
    msg.data = np.frombuffer(arr.tobytes(), dtype=np.uint8).copy()


def metrics_of(tum: Path) -> dict:
    return json.loads(tum.with_name(tum.stem + ".odom.metrics.json").read_text())


def pose_matrix(T) -> np.ndarray:
    return np.array(T, dtype=np.float64)


# ---------------------------------------------------------------- shared logs (built once)

@pytest.fixture(scope="module")
def sim(tmp_path_factory) -> dict:
    """Small simulated logs: handheld ROS 1 (2.5 s) and ROS 2 folder (2 s), corridor ROS 1 with wheels (2.5 s),
    a longer handheld (8 s) for timing, and what odom makes of the clean ones."""
    root = tmp_path_factory.mktemp("sim")
    logs = {"h": root / "h.bag", "h2": root / "h2", "c": root / "c.bag", "long": root / "long.bag"}
    for key, scenario, fmt, dur in (("h", "handheld", "ros1", "2.5"), ("h2", "handheld", "ros2", "2"),
                                    ("c", "corridor", "ros1", "2.5"), ("long", "handheld", "ros1", "8")):
        rc = main(["simulate", scenario, str(logs[key]), "--format", fmt, "--duration", dur, "--columns", "180",
                   "--seed", "3", "-q"])
        assert rc == 0
    logs["truth"] = json.loads((root / "h.truth.json").read_text())
    logs["gt_tum"] = root / "h.gt.tum"
    for key in ("h", "c"):
        out = root / f"{key}.clean.tum"
        assert main(["odom", str(logs[key]), "-o", str(out), "-q"]) == 0
        logs[f"{key}_metrics"] = metrics_of(out)
    return logs


@pytest.fixture(scope="module")
def clean_run(sim, tmp_path_factory) -> dict:
    """Peak memory and wall time of ``lio odom`` on the clean handheld log, as a process."""
    cwd = tmp_path_factory.mktemp("clean")
    run = lio_subprocess(["odom", sim["h"], "-o", cwd / "o.tum", "-q"], cwd)
    assert run["exit"] == 0, run["stderr"]
    return run


# ---------------------------------------------------------------- data loss

@pytest.mark.parametrize("command", ["odom", "deskew"])
@pytest.mark.parametrize("force", [False, True], ids=["no-force", "force"])
@pytest.mark.parametrize("case", ["same path", "symlink", "hard link", "ros2 folder", "file in ros2 folder",
                                  "new file in ros2 folder"])
def test_output_that_is_an_input_is_refused(sim, tmp_path, capsys, case, force, command):
    """An output is never an input: the same path, the same file through a symbolic or hard link, or anything
    inside an input folder (a ROS 2 bag) is refused with exit 2 and a line saying it 'is an input', with or
    without --force (which must not be suggested); the input and its folder are left byte for byte as they
    were and nothing is written beside them (``lio odom -o``, ``lio deskew LOG OUT``)."""
    bag, folder = tmp_path / "in.bag", tmp_path / "in_ros2"
    shutil.copy2(sim["h"], bag)
    shutil.copytree(sim["h2"], folder)
    out = tmp_path / ("out.tum" if command == "odom" else "out.bag")
    log = {"same path": bag, "symlink": bag, "hard link": bag}.get(case, folder)
    if case == "same path":
        out = bag
    elif case == "symlink":
        out.symlink_to(bag)
    elif case == "hard link":
        os.link(bag, out)
    elif case == "ros2 folder":
        out = folder
    elif case == "file in ros2 folder":
        out = folder / "metadata.yaml"
    else:
        out = folder / ("odom.tum" if command == "odom" else "d.bag")
    before, files = tree_hash(log), listing(tmp_path)
    args = ["odom", log, "-o", out] if command == "odom" else ["deskew", log, out]
    rc, _, err = lio(capsys, *args, "-q", *(["--force"] if force else []))
    assert rc == 2
    assert "is an input" in one_line(err)
    assert "--force" not in err
    assert tree_hash(log) == before
    assert listing(tmp_path) == files


@pytest.mark.parametrize("force", [False, True], ids=["no-force", "force"])
@pytest.mark.parametrize("case", ["csv onto the estimate", "csv onto a link to the estimate",
                                  "csv onto the bag's metadata", "csv inside the bag folder",
                                  "plot into the bag folder", "plot inside the bag folder"])
def test_evaluate_output_that_is_an_input_is_refused(sim, tmp_path, capsys, case, force):
    """``lio evaluate --csv/--plot`` never writes onto an input (GT or estimate, directly or through a link)
    nor inside an input folder (a ROS 2 bag given as ``FOLDER:/ground_truth``): exit 2, 'is an input', with or
    without --force, inputs untouched and no file created."""
    folder, est = tmp_path / "gt_ros2", tmp_path / "est.tum"
    shutil.copytree(sim["h2"], folder)
    shutil.copy2(sim["gt_tum"], est)
    target = {"csv onto the estimate": est, "csv onto a link to the estimate": tmp_path / "link.csv",
              "csv onto the bag's metadata": folder / "metadata.yaml", "csv inside the bag folder": folder / "e.csv",
              "plot into the bag folder": folder, "plot inside the bag folder": folder / "plots"}[case]
    if case == "csv onto a link to the estimate":
        target.symlink_to(est)
    flag = "--plot" if case.startswith("plot") else "--csv"
    before, files = (tree_hash(folder), tree_hash(est)), listing(tmp_path)
    rc, _, err = lio(capsys, "evaluate", f"{folder}:/ground_truth", est, flag, target, "-q",
                     *(["--force"] if force else []))
    assert rc == 2
    assert "is an input" in one_line(err)
    assert (tree_hash(folder), tree_hash(est)) == before
    assert listing(tmp_path) == files


def test_simulate_force_never_replaces_a_folder_that_is_not_a_log(tmp_path, capsys):
    """``lio simulate ... OUT --format ros2 --force`` replaces an earlier log at OUT, but a folder that is not a
    ROS 2 bag (here one holding a user's file) is never deleted: exit 2 naming the folder, its files intact."""
    folder = tmp_path / "my_data"
    folder.mkdir()
    (folder / "notes.txt").write_text("precious\n")
    rc, _, err = lio(capsys, "simulate", "handheld", folder, "--format", "ros2", "--duration", "1", "--columns",
                     "64", "--force", "-q")
    assert rc == 2
    assert str(folder) in one_line(err)
    assert (folder / "notes.txt").read_text() == "precious\n"
    assert listing(folder) == {"notes.txt"}


# ---------------------------------------------------------------- signals

_ANSI = re.compile(r"\x1b\[[0-9;?]*[A-Za-z]")


def _interrupt_when_working(args, cwd: Path) -> tuple[int, str]:
    """Start ``lio ARGS`` with stderr on a terminal and send SIGINT as soon as it shows its progress bar
    (the work has started); return (exit code, what it printed, escape codes and the bar removed)."""
    master, slave = pty.openpty()
    p = subprocess.Popen(lio_command() + [str(a) for a in args], cwd=cwd, env=_env(), stdin=subprocess.DEVNULL,
                         stdout=subprocess.DEVNULL, stderr=slave)
    os.close(slave)
    buf, sent, t0 = b"", False, time.monotonic()
    try:
        while time.monotonic() - t0 < MAX_WALL_S:
            ready, _, _ = select.select([master], [], [], 0.05)
            if ready:
                try:
                    chunk = os.read(master, 65536)
                except OSError:  # the child closed the terminal
                    break
                if not chunk:
                    break
                buf += chunk
                if not sent:
                    p.send_signal(signal.SIGINT)
                    sent = True
            elif p.poll() is not None:
                break
    finally:
        if p.poll() is None:
            p.kill()
        p.wait()
        os.close(master)
    assert sent, f"lio {' '.join(map(str, args))} showed no progress on a terminal, so it was never interrupted"
    text = _ANSI.sub("", buf.decode(errors="replace")).replace("\r", "\n")
    lines = [ln for ln in text.splitlines() if ln.strip() and "━" not in ln and not re.search(r"\d+%", ln)]
    return p.returncode, "\n".join(lines)


@pytest.mark.parametrize("command", ["odom", "info --check", "simulate", "deskew"])
def test_sigint_exits_130_with_one_line_and_no_temp_file(sim, tmp_path, command):
    """Ctrl-C (SIGINT) while ``odom``, ``info --check``, ``simulate`` or ``deskew`` (its writing process too)
    works exits 130 (not 0, which tells the shell the run succeeded) with one line on stderr saying it was
    'interrupted', no traceback, and leaves no file behind (no temp file, no partial output)."""
    args = {"odom": ["odom", sim["long"], "-o", tmp_path / "o.tum"],
            "info --check": ["info", "--check", sim["long"]],
            "simulate": ["simulate", "handheld", tmp_path / "s.bag", "--duration", "30"],
            "deskew": ["deskew", sim["long"], tmp_path / "d.bag", "--map", tmp_path / "d.ply"]}[command]
    rc, text = _interrupt_when_working(args, tmp_path)
    assert rc == 130, f"exit {rc}, stderr:\n{text}"
    assert "interrupted" in one_line(text)
    assert "Traceback" not in text
    assert listing(tmp_path) == set()


# ---------------------------------------------------------------- outputs checked before the work

@pytest.fixture(scope="module")
def long_trajectories(tmp_path_factory) -> tuple[Path, Path]:
    """Two 30 000-pose TUM trajectories (evaluate takes a few tenths of a second on them)."""
    root = tmp_path_factory.mktemp("traj")
    rng = np.random.default_rng(7)
    n = 30_000
    t = 1_700_000_000 + np.arange(n) * 0.01
    xyz = np.cumsum(rng.normal(0, 0.01, (n, 3)), axis=0)
    q = np.tile([0.0, 0.0, 0.0, 1.0], (n, 1))
    gt, est = root / "gt.tum", root / "est.tum"
    np.savetxt(gt, np.column_stack([t, xyz, q]), fmt="%.9f")
    np.savetxt(est, np.column_stack([t, xyz + rng.normal(0, 0.02, (n, 3)), q]), fmt="%.9f")
    return gt, est


_WORK_S: dict[str, float] = {}


@pytest.mark.parametrize("where", ["/proc", "under a file"])
@pytest.mark.parametrize("command", ["odom -o", "evaluate --csv", "evaluate --plot", "deskew"])
def test_unwritable_output_is_refused_before_the_work(sim, long_trajectories, tmp_path, capsys, command, where):
    """An output location that cannot be written (in /proc, or a path under a regular file) is bad input: exit 2
    with one line naming it, found before the work starts (well under the time the work takes), never an
    'internal error' with exit 1 after the whole run."""
    blocker = tmp_path / "a_file"
    blocker.write_text("x")
    name = {"odom -o": "o.tum", "evaluate --csv": "e.csv", "evaluate --plot": "plots", "deskew": "d.bag"}[command]
    bad = Path("/proc") / f"lio-test-{name}" if where == "/proc" else blocker / name
    ok = tmp_path / name

    def run(out: Path) -> tuple[int, str, float]:
        if command == "odom -o":
            args = ["odom", sim["long"], "-o", out, "-q"]
        elif command == "deskew":
            args = ["deskew", sim["long"], out, "-q"]
        else:
            args = ["evaluate", *long_trajectories, command.split()[1], out, "-q"]
        t0 = time.perf_counter()
        rc, _, err = lio(capsys, *args)
        return rc, err, time.perf_counter() - t0

    if command not in _WORK_S:  # the same command to a writable place: how long the work takes
        rc_ok, err_ok, _WORK_S[command] = run(ok)
        assert rc_ok == 0, err_ok
    work_s = _WORK_S[command]
    refused = []
    for _ in range(3):  # the fastest of three: one pause of a loaded machine is not the refusal's own time
        rc, err, refused_s = run(bad)
        assert rc == 2, err
        line = one_line(err)
        assert "internal error" not in line
        assert str(bad) in line or str(bad.parent) in line
        refused.append(refused_s)
    refused_s = min(refused)
    assert refused_s < EARLY_FRACTION * work_s, f"refused after {refused_s:.2f} s; the work takes {work_s:.2f} s"


# ---------------------------------------------------------------- bad values: exit 2, named

def test_pointfield_count_2_is_bad_input(sim, tmp_path, capsys):
    """A PointCloud2 whose x field declares ``count`` 2 is bad input for ``info --check`` and ``odom``: exit 2
    with one line naming the field and its count, not an internal error (broadcast shapes)."""
    def edit(topic, i, msg):
        if topic == LIDAR:
            msg.fields[0].count = 2  # x
        return msg

    log = rewrite(sim["h"], tmp_path / "count2.bag", edit)
    for args in (["info", "--check", log], ["odom", log, "-o", tmp_path / "o.tum", "-q"]):
        rc, _, err = lio(capsys, *args)
        assert rc == 2, err
        line = one_line(err)
        assert "count" in line and "'x'" in line
        assert "internal error" not in line


@pytest.mark.parametrize("field, value", [("imu_time_offset_s", "1.0e12"), ("imu_time_offset_s", ".nan"),
                                          ("imu_time_offset_s", ".inf"), ("T_base_imu", "nan matrix")])
def test_calibration_fields_out_of_range_exit_2(sim, tmp_path, capsys, field, value):
    """Every ``--calib`` field is checked for range and finiteness when the file is read: an IMU clock offset of
    1e12 s, NaN or inf, or an extrinsic holding NaN, is a config error (exit 2, one line naming the field), not
    an OverflowError or a run on garbage."""
    calib = tmp_path / "calib.yaml"
    if value == "nan matrix":
        T = [[1.0, 0.0, 0.0, ".nan"], [0.0, 1.0, 0.0, 0.0], [0.0, 0.0, 1.0, 0.0], [0.0, 0.0, 0.0, 1.0]]
        calib.write_text(f"{field}: [{', '.join('[' + ', '.join(map(str, r)) + ']' for r in T)}]\n")
    else:
        calib.write_text(f"{field}: {value}\n")
    rc, _, err = lio(capsys, "odom", sim["h"], "-o", tmp_path / "o.tum", "-q", "--calib", calib)
    assert rc == 2, err
    line = one_line(err)
    assert field in line
    assert "internal error" not in line


NUMERIC_CASES = {
    "evaluate --t-max-diff 1e300": (["--t-max-diff", "1e300"], "--t-max-diff"),
    "evaluate --t-offset 1e300": (["--t-offset", "1e300"], "--t-offset"),
    "evaluate --fail-above ape_rmse=nan": (["--fail-above", "ape_rmse=nan"], "--fail-above"),
    "evaluate --n-align 0": (["--n-align", "0"], "--n-align"),
    "evaluate --n-align -3": (["--n-align", "-3"], "--n-align"),
    "evaluate --delta-tol nan": (["--delta-tol", "nan"], "--delta-tol"),
    "evaluate --delta-tol -1": (["--delta-tol", "-1"], "--delta-tol"),
    "simulate --noise-scale nan": (["--noise-scale", "nan"], "--noise-scale"),
    "simulate --imu-time-offset nan": (["--imu-time-offset", "nan"], "--imu-time-offset"),
    "odom config static_init_s inf": ("static_init_s: .inf", "static_init_s"),
    "odom config gravity_mps2 nan": ("gravity_mps2: .nan", "gravity_mps2"),
    "odom config position_sigma_m inf": ("fusion: {position_sigma_m: .inf}", "position_sigma_m"),
    "odom config gyro_noise_radps 1e300": ("fusion: {imu: {gyro_noise_radps: 1.0e300}}", "gyro_noise_radps"),
}


@pytest.mark.parametrize("case", list(NUMERIC_CASES))
def test_numeric_options_out_of_range_exit_2(sim, tmp_path, capsys, case):
    """Every numeric option and config field is validated for range and finiteness before any work: exit 2 with
    one line naming it. Not an OverflowError (--t-max-diff/--t-offset 1e300, static_init_s inf), not a limit
    that never trips (--fail-above ape_rmse=nan), not a silently accepted --n-align 0 or -3 or --delta-tol NaN,
    not a log of NaN noise (--noise-scale nan), not a crash by SIGABRT (sigma inf, noise density 1e300; these
    run as a process)."""
    extra, name = NUMERIC_CASES[case]
    if case.startswith("odom"):
        (tmp_path / "cfg.yaml").write_text(extra + "\n")
        run = lio_subprocess(["odom", sim["h"], "-o", tmp_path / "o.tum", "-q", "--config", tmp_path / "cfg.yaml"],
                             tmp_path)
        rc, err = run["exit"], run["stderr"]
    elif case.startswith("simulate"):
        rc, _, err = lio(capsys, "simulate", "handheld", tmp_path / "s.bag", "--duration", "1", "--columns", "64",
                         "-q", *extra)
    else:
        rc, _, err = lio(capsys, "evaluate", sim["gt_tum"], sim["gt_tum"], "-q", *extra)
    assert rc == 2, err
    line = one_line(err)
    assert name in line
    assert "internal error" not in line


def test_info_refuses_a_fifo_instead_of_hanging(tmp_path):
    """``lio info`` (and ``odom``) on a FIFO, or anything that is neither a regular file nor a folder, answers at
    once with exit 2 and one line naming it (e.g. 'not a regular file'); it never blocks waiting for a writer."""
    fifo = tmp_path / "run.bag"
    os.mkfifo(fifo)
    for args in (["info", fifo], ["odom", fifo, "-o", tmp_path / "o.tum"]):
        run = lio_subprocess(args, tmp_path, timeout_s=10.0)
        assert run["exit"] is not None, f"lio {args[0]} on a FIFO still blocked after 10 s"
        assert run["exit"] == 2, run["stderr"]
        assert str(fifo) in one_line(run["stderr"])


# ---------------------------------------------------------------- hostile stamps and values: bounded, counted

@pytest.mark.parametrize("stamp", ["+1e6 s", "+1e7 s", "0", "2^31 s"])
def test_hostile_scan_stamp_costs_bounded_time_and_memory(sim, clean_run, tmp_path, stamp):
    """One scan stamped far from the others (+1e6 s, +1e7 s, 0 or 2^31 - 1 s) is a gap, handled and counted, never
    integrated sub-step by sub-step: odom exits 0 within the time bound, its peak memory stays within a margin
    of the clean log's (and under 1 GB), no numpy warning reaches stderr, and the other scans are still used."""
    def edit(topic, i, msg):
        if topic == LIDAR and i == 2:  # 0.2 s in: early enough to be taken in stamp order
            old = stamp_ns(msg)
            set_stamp(msg, {"+1e6 s": old + 10**6 * S_NS, "+1e7 s": old + 10**7 * S_NS, "0": 0,
                            "2^31 s": (2**31 - 1) * S_NS}[stamp])  # the largest stamp a header's int32 sec holds
        return msg

    log = rewrite(sim["h"], tmp_path / "stamp.bag", edit)
    run = lio_subprocess(["odom", log, "-o", tmp_path / "o.tum", "-q"], tmp_path, timeout_s=MAX_WALL_S)
    assert run["exit"] is not None, f"odom still running after {MAX_WALL_S} s"
    assert run["exit"] == 0, run["stderr"][-2000:]
    assert run["peak_rss_mb"] < min(MAX_RSS_MB, clean_run["peak_rss_mb"] + RSS_MARGIN_MB), run["peak_rss_mb"]
    assert not WARNING_TEXT.search(run["stderr"]), run["stderr"]
    assert metrics_of(tmp_path / "o.tum")["scans"]["used"] >= sim["h_metrics"]["scans"]["used"] - 2


@pytest.mark.parametrize("scan", [0, 12], ids=["first scan", "later scan"])
def test_absurd_point_time_drops_the_point_not_the_scans(sim, tmp_path, capsys, scan):
    """One point whose per-point time is finite but absurd (5e5 s) is a bad point: odom drops and counts it
    (``invalid_points_dropped``) and uses every scan the clean log uses (not 'too few points' for every later
    scan, not a misleading failure when it is in the first scan), with no numpy warning on stderr;
    ``info --check`` reports it (exit 2 naming the topic)."""
    def edit(topic, i, msg):
        if topic == LIDAR and i == scan:
            arr = cloud_array(msg)
            arr["time"][100] = 5e5
            set_cloud_array(msg, arr)
        return msg

    log = rewrite(sim["h"], tmp_path / "ptime.bag", edit)
    rc, _, err = lio(capsys, "odom", log, "-o", tmp_path / "o.tum", "-q")
    assert rc == 0, err
    assert not WARNING_TEXT.search(err), err
    m = metrics_of(tmp_path / "o.tum")
    assert m["scans"]["used"] == sim["h_metrics"]["scans"]["used"]
    assert m["stream"]["invalid_points_dropped"] >= 1
    rc, _, err = lio(capsys, "info", "--check", log)
    assert rc == 2
    assert LIDAR in one_line(err)


def test_imu_sample_1e300_is_dropped_without_numpy_warnings(sim, tmp_path, capsys):
    """An IMU sample of 1e300 m/s^2 is a bad sample: odom drops and counts it and runs on (exit 0, the scans of
    the clean log used) with no RuntimeWarning and no 'SVD did not converge'; ``info --check`` reports it
    (exit 2 naming the IMU topic)."""
    def edit(topic, i, msg):
        if topic == IMU and i == 300:
            msg.linear_acceleration.x = 1e300
        return msg

    log = rewrite(sim["h"], tmp_path / "imu.bag", edit)
    rc, _, err = lio(capsys, "odom", log, "-o", tmp_path / "o.tum", "-q")
    assert rc == 0, err
    assert not WARNING_TEXT.search(err), err
    assert metrics_of(tmp_path / "o.tum")["scans"]["used"] >= sim["h_metrics"]["scans"]["used"] - 1
    rc, _, err = lio(capsys, "info", "--check", log)
    assert rc == 2
    assert IMU in one_line(err)


def test_check_flags_a_scan_stamped_0_in_the_first_half_second(sim, tmp_path, capsys):
    """``info --check`` reports a scan whose header stamp is 0 among scans stamped in 2023 even when it is one of
    the first (0.3 s into the log): exit 2 with one line naming the LiDAR topic."""
    def edit(topic, i, msg):
        if topic == LIDAR and i == 3:
            set_stamp(msg, 0)
        return msg

    log = rewrite(sim["h"], tmp_path / "zero.bag", edit)
    rc, _, err = lio(capsys, "info", "--check", log)
    assert rc == 2
    assert LIDAR in one_line(err)


# ---------------------------------------------------------------- contradictory /tf_static

def _tf_edit(sim, how: str, scale: float = 1.0):
    T_base_imu, T_base_lidar = pose_matrix(sim["truth"]["T_base_imu"]), pose_matrix(sim["truth"]["T_base_lidar"])

    def edit(topic, i, msg):
        if topic != "/tf_static":
            return msg
        by_child = {tr.child_frame_id: tr for tr in msg.transforms}
        if how == "scale":
            q = by_child["lidar"].transform.rotation
            q.x, q.y, q.z, q.w = q.x * scale, q.y * scale, q.z * scale, q.w * scale
            return msg
        extra = copy.deepcopy(by_child["lidar"])
        if how == "cycle":  # lidar -> base back again, 0.5 m away from the inverse of base -> lidar
            T = np.linalg.inv(T_base_lidar)
            extra.header.frame_id, extra.child_frame_id = "lidar", "base"
        else:  # imu -> lidar directly, 0.5 m away from the path imu -> base -> lidar
            T = np.linalg.inv(T_base_imu) @ T_base_lidar
            extra.header.frame_id, extra.child_frame_id = "imu", "lidar"
        xyz, q = pose_to_xyz_quat(T)
        tr, rot = extra.transform.translation, extra.transform.rotation
        tr.x, tr.y, tr.z = float(xyz[0]) + 0.5, float(xyz[1]), float(xyz[2])
        rot.x, rot.y, rot.z, rot.w = (float(v) for v in q)
        msg.transforms.append(extra)
        return msg

    return edit


@pytest.mark.parametrize("how, frames", [("cycle", ("base", "lidar")), ("disagreement", ("imu", "lidar"))])
def test_contradictory_tf_static_stops_unless_calib_settles_it(sim, tmp_path, capsys, how, frames):
    """/tf_static edges that form a cycle or disagree (two paths between the same frames, here 0.5 m apart) are
    reported, naming the frames, and odom stops with exit 2; a --calib giving the extrinsics settles it (exit 0)."""
    log = rewrite(sim["h"], tmp_path / "tf.bag", _tf_edit(sim, how))
    rc, _, err = lio(capsys, "odom", log, "-o", tmp_path / "o.tum", "-q")
    assert rc == 2, err
    line = one_line(err)
    assert all(f in line for f in frames), line
    calib = tmp_path / "calib.yaml"
    truth = sim["truth"]
    calib.write_text(json.dumps({"T_base_imu": truth["T_base_imu"], "T_base_lidar": truth["T_base_lidar"]}))
    rc, _, err = lio(capsys, "odom", log, "-o", tmp_path / "o.tum", "-q", "--calib", calib)
    assert rc == 0, err


def test_non_unit_tf_quaternion_warns_only_when_far_from_unit(sim, tmp_path, capsys):
    """A /tf_static quaternion a little off unit length (x 1.0001, as rounded URDF values are) is normalised
    silently; one far from it (x 2) is normalised with a warning naming the frames and the quaternion."""
    near = rewrite(sim["h"], tmp_path / "near.bag", _tf_edit(sim, "scale", 1.0001))
    far = rewrite(sim["h"], tmp_path / "far.bag", _tf_edit(sim, "scale", 2.0))
    rc, _, err = lio(capsys, "odom", near, "-o", tmp_path / "near.tum", "-q")
    assert rc == 0, err
    assert "quaternion" not in err
    rc, _, err = lio(capsys, "odom", far, "-o", tmp_path / "far.tum", "-q")
    assert rc == 0, err
    warning = [ln for ln in err.splitlines() if "quaternion" in ln]
    assert len(warning) == 1 and warning[0].startswith("lio: warning:") and "lidar" in warning[0], err


# ---------------------------------------------------------------- real recordings

def test_mcap_with_ros1_encoded_messages_is_decoded(real_logs, capsys):
    """A bare MCAP whose messages are ROS 1 encoded (profile ros1, an Ouster OS1-64) is decoded like any other
    log: ``info`` describes its 64x2048 cloud (per-point time 't', Ouster), and ``info --check`` decodes both
    clouds and all 17 IMU samples."""
    log = real_logs / "ouster_os1_ros1_mcap" / "os1_64.mcap"
    rc, out, err = lio(capsys, "info", log, "--json")
    assert rc == 0, err
    scans = {s["topic"]: s for s in json.loads(out)["scans"]}
    cloud = scans["/os1_cloud_node/points"]
    assert (cloud["height"], cloud["width"]) == (64, 2048)
    assert cloud["time_convention"]["field"] == "t"
    rc, out, err = lio(capsys, "info", log, "--check", "--json")
    assert rc == 0, err
    checked = json.loads(out)["check"]["checked"]
    assert checked["/os1_cloud_node/points"] == 2
    assert checked["/os1_cloud_node/imu"] == 17


def test_check_with_nothing_checkable_exits_2(real_logs, capsys):
    """``info --check`` on a log without one decodable sensor message (only Ouster raw packets) does not pass
    with '0 sensor messages decoded': it says nothing checkable was found (exit 2, one line naming the log)."""
    log = real_logs / "ouster_raw_packets"
    rc, _, err = lio(capsys, "info", log, "--check")
    assert rc == 2
    assert "ouster_raw_packets" in one_line(err)


def _luminar_first_scan_truth(log: Path) -> tuple[int, int, int]:
    """(header stamp, first point time, last point time) of the first Luminar scan, from time_sec + time_nsec."""
    from rosbags.highlevel import AnyReader

    with AnyReader([log]) as r:
        conns = [c for c in r.connections if c.topic == "/luminar_pointcloud"]
        _, _, raw = next(r.messages(connections=conns))
        msg = r.deserialize(raw, conns[0].msgtype)
    arr = cloud_array(msg)
    t = arr["time_sec"].astype(np.int64) * S_NS + arr["time_nsec"].astype(np.int64)
    return stamp_ns(msg), int(t.min()), int(t.max())


def test_split_time_fields_are_detected_on_luminar(real_logs, capsys):
    """Per-point time split over ``time_sec`` + ``time_nsec`` (Luminar, absolute) is detected: ``info`` names both
    fields, does not claim azimuth-derived stamps (the scanner does not spin), reports the header at the scan's
    end (it equals the last point's time) and the true span (87.8 ms, within 0.5 ms)."""
    log = real_logs / "luminar_truck" / "luminar.bag"
    header_ns, first_ns, last_ns = _luminar_first_scan_truth(log)
    assert header_ns == last_ns  # the recording's own truth
    rc, out, err = lio(capsys, "info", log, "--json")
    assert rc == 0, err
    tc = next(s for s in json.loads(out)["scans"] if s["topic"] == "/luminar_pointcloud")["time_convention"]
    assert "azimuth" not in tc["description"] and tc["name"] != "azimuth", tc
    assert "time_sec" in tc["description"] and "time_nsec" in tc["description"], tc
    assert tc["header_stamp_marks"] == "end", tc
    assert math.isclose(tc["scan_duration_s"], (last_ns - first_ns) / S_NS, abs_tol=5e-4), tc


# ---------------------------------------------------------------- options that lose data

def test_point_time_none_with_constant_velocity_deskew_keeps_the_first_scan(sim, tmp_path, capsys):
    """``--point-time none --deskew constant-velocity`` uses every scan the default run uses, the first one
    included (a zero-length interpolation must not give NaN), with no RuntimeWarning on stderr."""
    rc, _, err = lio(capsys, "odom", sim["h"], "-o", tmp_path / "o.tum", "-q", "--point-time", "none",
                     "--deskew", "constant-velocity")
    assert rc == 0, err
    assert not WARNING_TEXT.search(err), err
    assert metrics_of(tmp_path / "o.tum")["scans"]["used"] == sim["h_metrics"]["scans"]["used"]


def test_twist_only_odometry_is_accepted_for_wheel_use(sim, tmp_path, capsys):
    """Wheel odometry whose pose quaternion is (0,0,0,0) but whose twist is valid (as ardrone_twist_only's) is
    accepted where only the twist is used: ``info --check`` passes and odom uses every wheel message the clean
    log gives it (the pose is not needed for a velocity update)."""
    def edit(topic, i, msg):
        if topic == WHEEL:
            q = msg.pose.pose.orientation
            q.x = q.y = q.z = q.w = 0.0
        return msg

    log = rewrite(sim["c"], tmp_path / "twist.bag", edit)
    rc, _, err = lio(capsys, "info", "--check", log)
    assert rc == 0, err
    rc, _, err = lio(capsys, "odom", log, "-o", tmp_path / "o.tum", "-q")
    assert rc == 0, err
    assert metrics_of(tmp_path / "o.tum")["scans"]["wheel_updates"] == sim["c_metrics"]["scans"]["wheel_updates"]


# ---------------------------------------------------------------- found by the fuzz run of 2026-11-24

@pytest.mark.parametrize("value", [float("nan"), 1e300], ids=["NaN", "1e300"])
def test_wheel_twist_nan_or_1e300_is_dropped_and_flagged_by_check(sim, tmp_path, value):
    """A wheel twist of NaN or 1e300 m/s is a bad sample like an IMU one: odom drops and counts it and runs on
    (exit 0, no warning text; it ended in SIGABRT or 'no scan could be used'), ``info --check`` reports it (exit
    2, one line naming the wheel topic and the twist)."""
    def edit(topic, i, msg):
        if topic == WHEEL and i == 10:
            msg.twist.twist.linear.x = value
        return msg

    log = rewrite(sim["c"], tmp_path / "wheel.bag", edit)
    run = lio_subprocess(["odom", log, "-o", tmp_path / "o.tum", "-q"], tmp_path)
    assert run["exit"] == 0, run["stderr"]
    assert not WARNING_TEXT.search(run["stderr"]), run["stderr"]
    m = metrics_of(tmp_path / "o.tum")
    assert m["stream"]["invalid_twists_dropped"] == 1
    assert m["scans"]["used"] == sim["c_metrics"]["scans"]["used"]
    run = lio_subprocess(["info", "--check", log], tmp_path)
    assert run["exit"] == 2
    line = one_line(run["stderr"])
    assert WHEEL in line and "twist at" in line


def _ate(log_gt: Path, est: Path, capsys) -> float:
    assert main(["evaluate", str(log_gt), str(est), "--json", "-q"]) == 0
    return json.loads(capsys.readouterr().out)["metrics"][0]["ape_rmse"]


@pytest.mark.parametrize("scan", [0, 3], ids=["first scan", "fourth scan"])
def test_a_scan_whose_points_share_one_stamp_keeps_the_track(sim, tmp_path, capsys, scan):
    """One cloud whose per-point times are all 0 (every point at the header stamp) puts two scan references a
    millisecond apart; the LiDAR-only start divided the motion by that millisecond, and every later scan failed
    until the run stopped as lost. Now: exit 0, every scan used, ATE within 2 cm of the clean run's."""
    def edit(topic, i, msg):
        if topic == LIDAR and i == scan:
            arr = cloud_array(msg)
            arr["time"] = 0.0
            set_cloud_array(msg, arr)
        return msg

    log = rewrite(sim["h"], tmp_path / "one_stamp.bag", edit)
    rc, _, err = lio(capsys, "odom", log, "-o", tmp_path / "o.tum", "-q")
    assert rc == 0, err
    assert metrics_of(tmp_path / "o.tum")["scans"]["used"] == sim["h_metrics"]["scans"]["used"]
    clean = tmp_path / "clean.tum"
    assert main(["odom", str(sim["h"]), "-o", str(clean), "-q"]) == 0
    assert _ate(sim["gt_tum"], tmp_path / "o.tum", capsys) < _ate(sim["gt_tum"], clean, capsys) + 0.02


def test_a_damaged_first_scan_restarts_the_map(sim, tmp_path, capsys):
    """A first cloud whose z field holds x (a damaged scan) made the map of a wrong world: no later scan matched
    it and the run stopped as lost. The map now starts again from a later scan when its only scan matches none
    of the next three: exit 0, a 'map restarted' event, the trajectory within 5 cm of the truth."""
    def edit(topic, i, msg):
        if topic == LIDAR and i == 0:
            arr = cloud_array(msg)
            arr["z"] = arr["x"]
            set_cloud_array(msg, arr)
        return msg

    log = rewrite(sim["h"], tmp_path / "bad_first.bag", edit)
    rc, _, err = lio(capsys, "odom", log, "-o", tmp_path / "o.tum", "-q")
    assert rc == 0, err
    events = metrics_of(tmp_path / "o.tum")["events"]
    assert [e["kind"] for e in events if e["kind"] == "map restarted"] == ["map restarted"]
    assert _ate(sim["gt_tum"], tmp_path / "o.tum", capsys) < 0.05
