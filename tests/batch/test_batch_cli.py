"""``lio batch`` on local processes: results equal the single command's byte for byte, the summary says what
happened, failing runs are recorded while the others go on, --resume, manifest errors, Ctrl-C."""

from __future__ import annotations

import contextlib
import csv
import io
import json
import math
import os
import shutil
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest
import yaml

import lio_cli
from lio_cli.batch.executors import DASK_INSTALL
from lio_cli.cli.app import main

VOLATILE = ("time_s", "time_per_scan_ms", "real_time_factor", "output")  # metrics that differ between any two runs
LIO = [sys.executable, "-c", "import sys; from lio_cli.cli.app import entry; sys.argv[0] = 'lio'; entry()"]
REL = 1e-6  # estimator floats in metrics.json may differ in their last bits between processes


def same_values(a, b, where="") -> None:
    """Equal JSON values; floats to ``REL`` (the trajectory file itself is compared byte for byte)."""
    if isinstance(a, dict):
        assert isinstance(b, dict) and a.keys() == b.keys(), where
        for k in a:
            same_values(a[k], b[k], f"{where}.{k}")
    elif isinstance(a, list):
        assert isinstance(b, list) and len(a) == len(b), where
        for i, (x, y) in enumerate(zip(a, b)):
            same_values(x, y, f"{where}[{i}]")
    elif isinstance(a, float) and isinstance(b, float):
        assert math.isclose(a, b, rel_tol=REL, abs_tol=1e-12), (where, a, b)
    else:
        assert a == b, (where, a, b)


def assert_as_single_command(sim, run: Path, name: str) -> None:
    """The batch run folder holds what ``lio odom LOG -o FILE --gt /ground_truth`` wrote."""
    ref = sim.ref_files(name)
    assert (run / "odom.tum").read_bytes() == ref["tum"].read_bytes()
    assert (run / "odom.config.yaml").read_bytes() == ref["config"].read_bytes()
    got, want = (json.loads(p.read_text()) for p in (run / "odom.metrics.json", ref["metrics"]))
    for m in (got, want):
        for k in VOLATILE:
            m.pop(k)
    same_values(got, want)


def run_lio(*argv: str) -> tuple[int, str]:
    """``lio ARGV`` in this process; (exit code, stdout)."""
    out = io.StringIO()
    with contextlib.redirect_stdout(out):
        rc = main([str(a) for a in argv])
    return rc, out.getvalue()


def summary_of(root: Path) -> dict:
    return json.loads((root / "summary.json").read_text())


def write_manifest(path: Path, text: str) -> Path:
    path.write_text(text)
    return path


@pytest.fixture(scope="module")
def pooled(sim, tmp_path_factory):
    """One batch over the three logs on two local processes, from a manifest with groups."""
    here = tmp_path_factory.mktemp("pooled")
    logs = sim.logs
    manifest = write_manifest(here / "runs.yaml", f"""\
output: out
defaults:
  gt: /ground_truth
runs:
  - log: {logs['walk_a'].parent}/walk_*.bag
    group: handheld
  - log: {logs['office']}
    group: office
""")
    rc, stdout = run_lio("batch", manifest, "--jobs", "2", "--json")
    return here, manifest, here / "out", rc, json.loads(stdout)


def test_local_pool_results_equal_single_command_runs_byte_for_byte(sim, pooled):
    _, _, out, rc, _ = pooled
    assert rc == 0
    for name in sim.logs:
        assert_as_single_command(sim, out / name, name)
        assert sorted(p.name for p in (out / name).iterdir()) == [
            "job.sha256", "odom.config.yaml", "odom.metrics.json", "odom.tum"]
    assert not [p for p in out.iterdir() if p.name.startswith(".")]  # no partial folder left


def test_summary_json_csv_and_group_statistics(sim, pooled):
    _, _, out, _, printed = pooled
    summary = summary_of(out)
    assert printed == summary  # --json prints what summary.json holds
    assert summary["counts"] == {"runs": 3, "ok": 3, "skipped": 0, "failed": 0, "not-run": 0}
    assert (summary["exit_code"], summary["executor"], summary["interrupted"]) == (0, "2 local processes", False)
    runs = {r["name"]: r for r in summary["runs"]}
    assert [r["name"] for r in summary["runs"]] == ["walk_a", "walk_b", "office"]  # the manifest's order
    for name, r in runs.items():
        metrics = json.loads((out / name / "odom.metrics.json").read_text())
        acc, m = metrics["accuracy"], r["metrics"]
        assert (r["status"], r["exit_class"], r["exit_code"], r["reason"], r["attempts"]) == ("ok", "ok", 0, "", 1)
        assert r["folder"] == str(out / name) and r["log"] == str(sim.logs[name])
        assert m["ate_m"] == round(acc["ate_trans_rmse_m"], 6) and m["rpe_m"] == round(acc["rpe_trans_rmse_m"], 6)
        assert m["ate_m"] < sim.thresholds[name]  # against the simulation's exact ground truth
        assert (m["scans_used"], m["scans_total"]) == (metrics["scans"]["used"], metrics["scans"]["total"])
        assert m["scans_total"] >= 35 and m["poses"] is None
        assert r["time_s"] > 0
    hh = summary["groups"]["handheld"]
    assert hh["runs"] == ["walk_a", "walk_b"]
    ates = [runs["walk_a"]["metrics"]["ate_m"], runs["walk_b"]["metrics"]["ate_m"]]
    ate = hh["metrics"]["ate_m"]
    assert ate["n"] == 2 and ate["min"] == min(ates) and ate["max"] == max(ates)
    assert math.isclose(ate["mean"], sum(ates) / 2, rel_tol=1e-12)
    assert math.isclose(ate["std"], abs(ates[0] - ates[1]) / math.sqrt(2), rel_tol=1e-9)  # sample std of two
    times = hh["metrics"]["time_s"]
    assert times["n"] == 2 and times["max"] == max(runs["walk_a"]["time_s"], runs["walk_b"]["time_s"])
    office = summary["groups"]["office"]["metrics"]["ate_m"]
    assert (office["n"], office["std"], office["mean"]) == (1, None, runs["office"]["metrics"]["ate_m"])
    rows = list(csv.DictReader((out / "summary.csv").open()))
    assert [r["name"] for r in rows] == ["walk_a", "walk_b", "office"]
    for row in rows:
        r = runs[row["name"]]
        assert (row["status"], row["group"], row["command"], row["log"]) == ("ok", r["group"], "odom", r["log"])
        assert float(row["ate_m"]) == r["metrics"]["ate_m"] and row["poses"] == ""


def test_fuse_and_deskew_runs_equal_their_single_commands(sim, tmp_path):
    """The batch's runs are the single commands' jobs: the same bytes, but for the de-skewed points' last bits
    (kiss-icp's sums over its threads differ in them from run to run: README, deskew)."""
    log = sim.logs["walk_a"]
    ref = tmp_path / "ref"
    ref.mkdir()
    assert main(["fuse", str(log), "-o", str(ref / "f.tum"), "-q"]) == 0
    assert main(["deskew", str(log), str(ref / "d.bag"), "-q"]) == 0
    manifest = write_manifest(tmp_path / "runs.yaml", f"""\
output: out
defaults: {{command: fuse}}
runs:
  - log: {log}
    name: fused
  - log: {log}
    name: deskewed
    command: deskew
""")
    rc, _ = run_lio("batch", manifest, "--jobs", "1", "-q")
    assert rc == 0
    out = tmp_path / "out"
    assert (out / "fused" / "fuse.tum").read_bytes() == (ref / "f.tum").read_bytes()
    assert (out / "fused" / "fuse.config.yaml").read_bytes() == (ref / "f.fuse.config.yaml").read_bytes()
    assert_same_log_but_last_bits(out / "deskewed" / "deskew.bag", ref / "d.bag", "/points")
    assert (out / "deskewed" / "deskew.config.yaml").read_bytes() == (ref / "d.deskew.config.yaml").read_bytes()
    deskew = summary_of(out)["runs"][1]["metrics"]
    assert deskew["scans_used"] == deskew["scans_total"] == sim_scans(ref / "d.deskew.metrics.json")


def assert_same_log_but_last_bits(a: Path, b: Path, lidar: str) -> None:
    """Every message of ``a`` and ``b`` the same (topic, record time, bytes), but the clouds of ``lidar``, whose
    points agree to 1e-9 m with everything else of the cloud equal."""
    import numpy as np

    from lio_cli.io.messages.pointcloud import decode_pointcloud2
    from lio_cli.io.logs.reader import open_log

    with open_log(a) as ra, open_log(b) as rb:
        assert [(c.topic, c.msgtype) for c in ra.connections] == [(c.topic, c.msgtype) for c in rb.connections]
        for (ta, ma), (tb, mb) in zip(((r.connection.topic, r) for r in ra.records()),
                                      ((r.connection.topic, r) for r in rb.records()), strict=True):
            assert (ta, ma.log_time_ns) == (tb, mb.log_time_ns)
            if ta != lidar or ma.data == mb.data:
                assert ma.data == mb.data
                continue
            ca, cb = decode_pointcloud2(ra.decode(ma)), decode_pointcloud2(rb.decode(mb))
            assert (ca.stamp_ns, ca.frame_id) == (cb.stamp_ns, cb.frame_id)
            np.testing.assert_array_equal(ca.point_stamps_ns, cb.point_stamps_ns)
            np.testing.assert_allclose(ca.points, cb.points, rtol=0, atol=1e-9)


def _leaves(node, path=""):
    """(path, value) of every leaf of a YAML document."""
    if isinstance(node, dict):
        for k, v in node.items():
            yield from _leaves(v, f"{path}.{k}")
    elif isinstance(node, list):
        for i, v in enumerate(node):
            yield from _leaves(v, f"{path}[{i}]")
    else:
        yield path, node


def test_calibrate_runs_equal_the_single_command(sim, tmp_path):
    """A batch calibrate run writes the .config.yaml the single ``lio calibrate`` writes byte for byte, and its
    calibration to the last digits: kiss-icp's threaded sums differ in their last bits between runs of one
    process, and the calibration's iterative fits can carry that to the 9th printed digit (a fresh process
    repeats itself exactly). A calibrate run with gt is a manifest error (it writes nothing to score)."""
    log = sim.logs["walk_a"]
    ref = tmp_path / "ref"
    ref.mkdir()
    assert main(["calibrate", str(log), "-o", str(ref / "c.yaml"), "-q"]) == 0
    manifest = write_manifest(tmp_path / "runs.yaml", f"""\
output: out
runs:
  - log: {log}
    name: cal
    command: calibrate
""")
    rc, _ = run_lio("batch", manifest, "--jobs", "1", "-q")
    assert rc == 0
    out = tmp_path / "out" / "cal"
    ours = dict(_leaves(yaml.safe_load((out / "calib.yaml").read_text())))
    theirs = dict(_leaves(yaml.safe_load((ref / "c.yaml").read_text())))
    assert ours.keys() == theirs.keys() and len(ours) > 20
    for key, value in theirs.items():
        if isinstance(value, float):
            assert ours[key] == pytest.approx(value, rel=1e-6, abs=1e-8), key
        else:
            assert ours[key] == value, key
    assert (out / "calib.config.yaml").read_bytes() == (ref / "c.calib.config.yaml").read_bytes()
    assert summary_of(tmp_path / "out")["runs"][0]["status"] == "ok"
    bad = write_manifest(tmp_path / "bad.yaml", manifest.read_text().replace("command: calibrate",
                                                                             "command: calibrate\n    gt: /ground_truth"))
    assert run_lio("batch", bad, "--jobs", "1", "-q")[0] == 2


def sim_scans(metrics: Path) -> int:
    return json.loads(metrics.read_text())["scans"]["total"]


def test_resume_skips_finished_runs_of_the_same_job_and_redoes_the_others(sim, pooled, tmp_path):
    here, manifest, out, _, _ = pooled
    shutil.copytree(out, tmp_path / "out")
    copy = write_manifest(tmp_path / "runs.yaml", manifest.read_text())
    out = tmp_path / "out"
    stamps = {n: (out / n / "odom.tum").stat().st_mtime_ns for n in sim.logs}

    rc, _ = run_lio("batch", copy, "--jobs", "1", "-q")
    assert rc == 2  # an earlier batch is there: neither --resume nor --force

    rc, _ = run_lio("batch", copy, "--jobs", "1", "--resume", "-q")
    assert rc == 0
    summary = summary_of(out)
    assert [r["status"] for r in summary["runs"]] == ["skipped"] * 3
    assert summary["runs"][0]["reason"] == "finished earlier by the same job"
    assert {n: (out / n / "odom.tum").stat().st_mtime_ns for n in sim.logs} == stamps
    assert summary["groups"]["handheld"]["metrics"]["ate_m"]["n"] == 2  # metrics read back from the folders

    # another job for the office run (an option changed), and walk_a's folder gone: those two run again
    office = "    group: office\n"
    copy.write_text(copy.read_text().replace(office, office + "    options: {fusion.method: complementary}\n"))
    shutil.rmtree(out / "walk_a")
    rc, _ = run_lio("batch", copy, "--jobs", "1", "--resume", "-q")
    assert rc == 0
    assert [r["status"] for r in summary_of(out)["runs"]] == ["ok", "skipped", "ok"]
    assert "method: complementary" in (out / "office" / "odom.config.yaml").read_text()
    assert_as_single_command(sim, out / "walk_a", "walk_a")
    assert (out / "walk_b" / "odom.tum").stat().st_mtime_ns == stamps["walk_b"]


def test_failing_runs_are_recorded_and_the_others_go_on(sim, tmp_path):
    bad = tmp_path / "truncated.bag"
    bad.write_bytes(sim.logs["walk_a"].read_bytes()[:3000])
    gone = tmp_path / "gone.bag"
    manifest = write_manifest(tmp_path / "runs.yaml", f"""\
output: out
defaults: {{gt: /ground_truth}}
runs:
  - log: {sim.logs['walk_a']}
  - log: {bad}
  - log: {gone}
  - log: {sim.logs['walk_b']}
    gt: no_such_gt.tum
""")
    rc, stdout = run_lio("batch", manifest, "--jobs", "1", "-q", "--json")
    assert rc == 1
    out = tmp_path / "out"
    summary = json.loads(stdout)
    assert summary["counts"] == {"runs": 4, "ok": 1, "skipped": 0, "failed": 3, "not-run": 0}
    assert summary["exit_code"] == 1
    runs = {r["name"]: r for r in summary["runs"]}
    host = runs["walk_a"]["worker"].split(":")[0]
    assert [(r["status"], r["exit_class"], r["exit_code"]) for r in summary["runs"]] == [
        ("ok", "ok", 0), ("failed", "input", 2), ("failed", "input", 2), ("failed", "input", 2)]
    assert runs["truncated"]["reason"].startswith(f"{bad}: cannot open as ros1 log (")
    assert runs["gone"]["reason"] == (f"{gone}: no such file or folder on {host} (lio batch reads logs and writes "
                                      "results by path: they must be on storage every worker shares)")
    # as lio odom --gt: an absolute path that is no file is tried as a topic of the log; in an existing folder
    # and no topic either, it is the missing file it most likely is
    assert runs["walk_b"]["reason"] == f"{tmp_path / 'no_such_gt.tum'}: no such file, nor a topic of {sim.logs['walk_b']}"
    for name in ("truncated", "gone", "walk_b"):
        assert runs[name]["folder"] is None and runs[name]["metrics"]["ate_m"] is None
    # the finished run is complete and as the single command's; a failed run leaves no folder, even half-written
    assert sorted(p.name for p in out.iterdir()) == ["summary.csv", "summary.json", "walk_a"]
    assert_as_single_command(sim, out / "walk_a", "walk_a")


@pytest.mark.parametrize("text, message", [
    ("runs: []\n", "{m}: runs: List should have at least 1 item after validation, not 0"),
    ("runs:\n  - lg: a.bag\n", "{m}: runs[0]: log: Field required"),
    ("runs:\n  - log: a.bag\n    command: evaluate\n",
     "{m}: runs[0]: command: Input should be 'odom', 'fuse', 'deskew' or 'calibrate'"),
    ("runs:\n  - log: a.bag\n    options: {{priorr: imu}}\n",
     "{m}: runs[0]: options: priorr: Extra inputs are not permitted"),
    ("runs:\n  - log: a.bag\n    options: {{fusion: {{alpha: 2}}}}\n",
     "{m}: runs[0]: options: fusion.alpha: must be within [0, 1], got 2"),
    ("runs:\n  - log: a.bag\n  - log: sub/a.bag\n",
     "{m}: runs[1]: two runs are named 'a' ({d}/a.bag and {d}/sub/a.bag); set name: on one of them, or name every "
     "run by its folder too: name: '{{parent}}_{{stem}}' (the shorthand: --name '{{parent}}_{{stem}}')"),
    ("runs:\n  - log: 'nothing/*.bag'\n", "{m}: runs[0]: log: 'nothing/*.bag' matches no file or folder"),
    ("runs:\n  - log: a.bag\n    command: deskew\n    gt: /ground_truth\n",
     "{m}: runs[0]: gt: deskew writes no trajectory to score; drop gt"),
    ("- a.bag\n", "{m}: manifest must be a mapping of option: value"),
])
def test_bad_manifest_exits_2_with_one_line(tmp_path, capsys, text, message):
    manifest = write_manifest(tmp_path / "m.yaml", ("output: out\n" if text.startswith("runs") else "") + text.format())
    rc = main(["batch", str(manifest)])
    err = capsys.readouterr().err
    assert rc == 2
    assert err == f"lio: error: {message.format(m=manifest, d=tmp_path)}\n"
    assert not (tmp_path / "out").exists()


def test_bad_options_exit_2(sim, tmp_path, capsys, monkeypatch):
    log = str(sim.logs["walk_a"])
    cases = [
        (["batch", "odom", log], "no output root: give -O DIR (or output: in the manifest)"),
        (["batch", "odom", log, "-O", tmp_path / "o", "--set", "prior"],
         "--set takes FIELD=VALUE (e.g. prior=constant-velocity), got 'prior'"),
        (["batch", "odom", log, "-O", tmp_path / "o", "--set", "prior=sometimes"],
         "lio batch: runs[0]: options: prior: Input should be 'imu', 'constant-velocity', 'wheel' or 'none'"),
        (["batch", "odom", log, "-O", tmp_path / "o", "--workers", "2"],
         "--workers goes with --dask local; for local processes use --jobs N"),
        (["batch", "odom", log, "-O", tmp_path / "o", "--dask", "local", "--jobs", "2"],
         "--jobs and --dask exclude each other: with --dask the cluster's workers run the logs"),
    ]
    for argv, message in cases:
        assert main([str(a) for a in argv]) == 2
        assert capsys.readouterr().err == f"lio: error: {message}\n"
    monkeypatch.setitem(sys.modules, "distributed", None)  # as without the dask extra
    assert main(["batch", "odom", log, "-O", str(tmp_path / "o"), "--dask", "local"]) == 2
    assert capsys.readouterr().err == f"lio: error: {DASK_INSTALL}\n"
    assert DASK_INSTALL == ("--dask needs the optional Dask dependency: pip install 'lio-cli[dask]' "
                            "(or pip install 'dask[distributed]')")
    assert not (tmp_path / "o").exists()


def test_a_killed_local_worker_has_its_run_retried_once(sim, tmp_path):
    out = tmp_path / "out"
    env = {**os.environ, "PYTHONPATH": str(Path(lio_cli.__file__).parents[1])}
    proc = subprocess.Popen([*LIO, "batch", "odom", *map(str, sim.logs.values()), "--gt", "/ground_truth", "-O",
                             str(out), "--jobs", "2", "-q"], env=env, stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                            text=True)
    try:
        victim = None
        deadline = time.monotonic() + 120
        while victim is None and proc.poll() is None and time.monotonic() < deadline:
            for attempt in out.glob(".*.partial-*/attempt.json"):  # a run a pool process is writing now
                try:
                    pid = json.loads(attempt.read_text())["pid"]
                except (OSError, ValueError):
                    continue
                os.kill(pid, signal.SIGKILL)
                victim = attempt.parent.name[1:].split(".partial-")[0]
                break
            time.sleep(0.01)
        assert victim is not None, "no run was seen under way"
        _, err = proc.communicate(timeout=300)
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()
    assert proc.returncode == 0, err
    summary = summary_of(out)
    assert summary["counts"]["ok"] == 3
    assert {r["name"]: r["attempts"] for r in summary["runs"]}[victim] == 2  # the killed attempt, then the retry
    for name in sim.logs:
        assert_as_single_command(sim, out / name, name)
    assert not [p for p in out.iterdir() if p.name.startswith(".")]


def test_a_run_folder_is_never_an_input(sim, tmp_path, capsys):
    log = tmp_path / "walk_a"  # a log: a folder of (split) ROS 1 bags, named as its run would be
    log.mkdir()
    shutil.copy(sim.logs["walk_a"], log / "walk_a.bag")
    assert main(["batch", "odom", str(log), "-O", str(tmp_path), "--force", "-q"]) == 2
    assert capsys.readouterr().err == (f"lio: error: {log}: is an input of this run (the input {log}); lio never "
                                       "writes over its inputs, whatever the options: choose another output\n")
    assert sorted(p.name for p in tmp_path.iterdir()) == ["walk_a"] and (log / "walk_a.bag").exists()


def test_ctrl_c_keeps_finished_runs_complete_and_leaves_no_half_written_one(sim, tmp_path):
    entries = "".join(f"  - log: {log}\n    name: {name}{k}\n" for k in range(2) for name, log in sim.logs.items())
    manifest = write_manifest(tmp_path / "runs.yaml", f"output: out\ndefaults: {{gt: /ground_truth}}\nruns:\n{entries}")
    out = tmp_path / "out"
    env = {**os.environ, "PYTHONPATH": str(Path(lio_cli.__file__).parents[1])}
    cmd = [*LIO, "batch", str(manifest), "--jobs", "2", "-q"]
    proc = subprocess.Popen(cmd, env=env, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    try:
        deadline = time.monotonic() + 120
        while not list(out.glob("*/job.sha256")) and proc.poll() is None and time.monotonic() < deadline:
            time.sleep(0.02)
        proc.send_signal(signal.SIGINT)
        _, err = proc.communicate(timeout=120)
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()
    assert proc.returncode == 130, err
    assert err.strip().endswith("lio: interrupted; nothing half-written was left behind")
    summary = summary_of(out)
    assert summary["interrupted"] and summary["exit_code"] == 1
    done = [r["name"] for r in summary["runs"] if r["status"] == "ok"]
    assert 1 <= len(done) < 6
    assert all(r["status"] == "not-run" and r["exit_class"] == "interrupted" for r in summary["runs"]
               if r["name"] not in done)
    folders = sorted(p.name for p in out.iterdir() if p.is_dir())
    assert folders == sorted(done)  # finished runs only: no partial folder, no half-written run
    for name in done:
        assert_as_single_command(sim, out / name, name[:-1])


def test_force_never_replaces_a_folder_no_run_wrote(sim, pooled, tmp_path, capsys):
    """--force redoes finished runs, but a folder at a run's place that no run wrote (no job hash inside: a
    user's own data) is refused before any run starts, exit 2 naming it, its files intact."""
    _, manifest, out, _, _ = pooled
    shutil.copytree(out, tmp_path / "out")
    copy = write_manifest(tmp_path / "runs.yaml", manifest.read_text())
    out = tmp_path / "out"
    shutil.rmtree(out / "walk_a")
    (out / "walk_a").mkdir()
    (out / "walk_a" / "notes.txt").write_text("precious\n")
    before = (out / "walk_b" / "odom.tum").stat().st_mtime_ns
    capsys.readouterr()
    rc, _ = run_lio("batch", copy, "--jobs", "1", "--force", "-q")
    assert rc == 2
    assert capsys.readouterr().err.strip() == (f"lio: error: {out / 'walk_a'}: is a folder that is not an output "
                                               "lio wrote; lio replaces only such folders, even with --force: "
                                               "choose another output")
    assert (out / "walk_a" / "notes.txt").read_text() == "precious\n"
    assert sorted(p.name for p in (out / "walk_a").iterdir()) == ["notes.txt"]
    assert (out / "walk_b" / "odom.tum").stat().st_mtime_ns == before


@pytest.mark.parametrize("second, fresh", [("calibrate", True), ("odom", False)])
def test_runs_asking_for_different_registration_threads_each_get_a_fresh_process(sim, tmp_path, monkeypatch,
                                                                                 second, fresh):
    """kiss-icp keeps the thread count of a process's first registration. With --jobs 1 the runs go in this
    process, but a calibrate run (1 thread: its result repeats exactly) beside an odom run asking for all cores
    gets a worker process of its own, as each run does then."""
    from lio_cli.batch import executors

    real, seen = executors.ProcessPoolExecutor, []

    def recording(*args, **kwargs):
        seen.append(kwargs.get("max_tasks_per_child"))
        return real(*args, **kwargs)

    monkeypatch.setattr(executors, "ProcessPoolExecutor", recording)
    log = sim.logs["walk_a"]
    manifest = write_manifest(tmp_path / "runs.yaml", f"""\
output: out
runs:
  - log: {log}
    name: first
    options: {{registration.threads: 0}}
  - log: {log}
    name: second
    command: {second}
    options: {{registration.threads: {0 if second == "odom" else 1}}}
""")
    assert run_lio("batch", manifest, "--jobs", "1", "-q")[0] == 0
    assert seen == ([1] if fresh else [])  # one worker, a fresh one per run; else the runs run in this process
    assert [r["status"] for r in summary_of(tmp_path / "out")["runs"]] == ["ok", "ok"]


def test_registration_threads_of_each_command():
    from lio_cli.batch.commands import registration_threads
    from lio_cli.config.calibrate import CalibrateConfig
    from lio_cli.config.deskew import DeskewConfig
    from lio_cli.config.fuse import FuseConfig
    from lio_cli.config.odom import OdomConfig

    assert registration_threads("odom", OdomConfig()) == 1
    assert registration_threads("calibrate", CalibrateConfig()) == 1
    assert registration_threads("deskew", DeskewConfig()) == 1
    assert registration_threads("deskew", DeskewConfig.model_validate({"trajectory": {"path": "x.tum"}})) is None
    assert registration_threads("fuse", FuseConfig()) is None
