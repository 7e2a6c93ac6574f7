"""``lio deskew`` writing beside its odometry: the odometry's settled poses, the pose feed's splines, and the
helper process, which must write the same bytes as one process and leave nothing behind when either side fails."""

import dataclasses
import re
import signal
import time
from pathlib import Path

import numpy as np
import pytest

from lio_cli.config import with_overrides
from lio_cli.config.deskew import DeskewConfig
from lio_cli.core.deskew.sweep_motion import PoseSpline, sweep_knots
from lio_cli.errors import InputError, ProcessingError
from lio_cli.jobs.deskew import job as deskew_job
from lio_cli.jobs.deskew import helper as deskew_helper, poses as deskew_poses
from lio_cli.jobs.deskew.job import DeskewJob, run_deskew, write_deskew
from lio_cli.jobs.deskew.poses import PoseFeed
from lio_cli.jobs.odom.job import OdomJob, SettledPose, run_odom
from lio_cli.simulation.run import simulate
from lio_cli.so3 import so3_exp

BESIDE = "beside the odometry, in a second process"


@pytest.fixture(scope="module")
def walk(tmp_path_factory) -> Path:
    """3 s handheld, already moving at the first scan (the start-up window's poses are replaced)."""
    root = tmp_path_factory.mktemp("helper")
    return simulate("handheld", root / "walk.bag", "ros1", duration_s=3.0, seed=5, columns=128, start="moving").log_path


@pytest.fixture()
def two_cores(monkeypatch):
    monkeypatch.setattr(deskew_helper, "usable_cpus", lambda: 2)  # the helper runs wherever the suite does


def run(log, out, helper, *, map=None, **overrides):
    cfg = with_overrides(DeskewConfig(), overrides)
    result = run_deskew(DeskewJob(Path(log), Path(out), cfg, map, helper=helper))
    write_deskew(result, Path(out), False)
    return result


def leftovers(folder: Path, stem: str) -> list[str]:
    return sorted(p.name for p in folder.iterdir() if stem in p.name)


def test_settled_poses_are_the_trajectory_each_once_in_order(walk):
    got: list[SettledPose] = []
    res = run_odom(OdomJob(walk), settled=got.extend)
    traj = res.trajectory
    assert [p.stamp_ns for p in got] == traj.stamps_ns.tolist()
    level = traj.poses[0] @ np.linalg.inv(got[0].pose)
    np.testing.assert_allclose(level[:3, :3] @ level[:3, :3].T, np.eye(3), atol=1e-12)
    np.testing.assert_allclose(level @ np.stack([p.pose for p in got]), traj.poses, atol=1e-9)
    assert res.metrics["start"]["kind"] == "moving"
    biased = [p.gyro_bias_radps is not None for p in got]
    assert all(biased)  # the start-up window's poses settle only once the IMU state started from them
    np.testing.assert_array_equal(got[-1].gyro_bias_radps, res.metrics["final_gyro_bias_radps"])


def _trajectory(n: int, gap_at: int | None = None) -> tuple[np.ndarray, np.ndarray]:
    rng = np.random.default_rng(1)
    steps = np.full(n - 1, 100_000_000) + rng.integers(-3_000_000, 3_000_000, n - 1)
    if gap_at is not None:
        steps[gap_at] = 900_000_000
    stamps = 1_000_000_000 + np.concatenate([[0], np.cumsum(steps)])
    t = (stamps - stamps[0]) * 1e-9
    poses = np.tile(np.eye(4), (n, 1, 1))
    poses[:, :3, :3] = so3_exp(np.stack([0.1 * np.sin(t), 0.2 * np.cos(0.7 * t), 1.5 * t], axis=1))
    poses[:, :3, 3] = np.stack([np.sin(t), 0.3 * t**2, 0.1 * t], axis=1)
    return stamps.astype(np.int64), poses


def _whole(stamps, poses, t1_ns):
    """The spline over the whole trajectory as the one-pass writer had it: extrapolated at the start by the
    median interval of the first 21 poses, at the end by the median of all."""
    steps = np.diff(stamps)
    step = int(np.median(steps if t1_ns > stamps[-1] else steps[:20]))
    return PoseSpline(stamps, poses, cubic=True, extrapolate_ns=step, max_gap_ns=500_000_000)


def _feed(stamps, poses, seed=2):
    rng = np.random.default_rng(seed)
    n = len(stamps)
    cuts = np.sort(rng.choice(np.arange(1, n), min(12, n - 1), replace=False))
    batches = [[SettledPose(int(s), p, None, 0) for s, p in zip(stamps[a:b], poses[a:b])]
               for a, b in zip([0, *cuts], [*cuts, n])]
    return PoseFeed(iter(batches), max_gap_ns=500_000_000, offset_ns=0, default_bias=np.zeros(3))


def _same(part, whole, t0, t1):
    assert part.uncovered(t0, t1) == whole.uncovered(t0, t1), (t0, t1)
    if whole.uncovered(t0, t1) is None:
        knots = sweep_knots(t0, t1, 5_000_000)
        np.testing.assert_allclose(part.at(knots), whole.at(knots), rtol=0, atol=1e-12)
        np.testing.assert_allclose(part.positions(knots), whole.positions(knots), rtol=0, atol=1e-12)


def test_the_feed_s_spline_is_the_whole_trajectory_s_spline_at_every_sweep():
    """In batches of any size, sweeps at the ends (extrapolated), across a gap, out of order, beyond the end."""
    stamps, poses = _trajectory(60, gap_at=30)
    feed = _feed(stamps, poses)
    step = int(np.median(np.diff(stamps)))
    ends = [*stamps.tolist(), int(stamps[-1]) + step // 2, int(stamps[-1]) + 2 * step]
    sweeps = [(t1 - 100_000_000, t1) for t1 in ends]
    sweeps.insert(20, (int(stamps[5]) - 40_000_000, int(stamps[5]) + 10_000_000))  # out of order
    sweeps.insert(0, (int(stamps[0]) - 3 * step, int(stamps[0]) - 2 * step))  # before the start
    reasons = set()
    for t0, t1 in sweeps:
        whole = _whole(stamps, poses, t1)
        reasons.add(whole.uncovered(t0, t1))
        _same(feed.spline(t0, t1), whole, t0, t1)
    assert reasons == {None, "before the trajectory starts", "after the trajectory ends", "in a gap of the trajectory"}


def test_the_feed_lets_go_of_old_poses_but_not_of_those_a_sweep_needs(monkeypatch):
    """With 8 poses kept: a sweep whose poses are gone is 'out of order'; one sweep stamped far ahead (a broken
    scan) does not take the poses the next sweeps need."""
    monkeypatch.setattr(deskew_poses, "_KEEP", 8)
    stamps, poses = _trajectory(80)
    feed = _feed(stamps, poses, seed=4)
    for k in range(1, 30):
        _same(feed.spline(int(stamps[k]) - 100_000_000, int(stamps[k])), _whole(stamps, poses, stamps[k]),
              int(stamps[k]) - 100_000_000, int(stamps[k]))
    assert feed.dropped > 0
    far = int(stamps[70])
    _same(feed.spline(far - 100_000_000, far), _whole(stamps, poses, far), far - 100_000_000, far)
    for k in range(30, 40):  # the broken scan's neighbours
        t0, t1 = int(stamps[k]) - 100_000_000, int(stamps[k])
        _same(feed.spline(t0, t1), _whole(stamps, poses, t1), t0, t1)
    first_kept = int(feed._stamps[0])
    assert feed.spline(first_kept - 10_000_000, first_kept + 5_000_000) == "more than 600 scans out of order"
    assert feed.spline(first_kept + 1_000_000, first_kept + 5_000_000) == "more than 600 scans out of order"


def test_the_feed_gives_each_sweep_the_bias_and_offset_of_its_own_pose():
    stamps, poses = _trajectory(6)
    settled = [SettledPose(int(s), p, None if i < 2 else np.full(3, 0.01 * i), 1000 * i)
               for i, (s, p) in enumerate(zip(stamps, poses))]
    feed = PoseFeed(iter([settled]), max_gap_ns=None, offset_ns=50, default_bias=np.full(3, -1.0))
    feed.drain()
    assert feed.imu_state(int(stamps[0]))[0].tolist() == [-1.0] * 3  # before the IMU state: the calibration's
    bias, offset = feed.imu_state(int(stamps[3]))
    assert bias.tolist() == [0.03] * 3 and offset == 3050
    assert feed.imu_state(int(stamps[3]) - 1)[1] == 3050  # a sweep ending before a pose takes that pose's
    assert feed.imu_state(int(stamps[-1]) + 10**9)[1] == 5050  # beyond the last: the last
    final = PoseFeed(iter([settled]), max_gap_ns=None, offset_ns=50, default_bias=np.zeros(3), final_offset_ns=7)
    final.drain()
    assert final.imu_state(int(stamps[1]))[1] == 7


def replaying(real, edit=lambda result: result):
    """A ``run_odometry`` that runs the odometry once (its result passed through ``edit``) and after that hands
    the same poses on again."""
    recorded = []

    def replay(log, cfg, source, progress, reader, settled=None):
        if not recorded:
            recorded.append(edit(real(log, cfg, source, progress, reader, settled)))
        elif settled is not None:
            for batch in recorded[0].batches:
                settled(batch)
        return recorded[0]

    return replay, recorded


@pytest.mark.parametrize("motion", ["imu", "constant-velocity"])
def test_the_helper_writes_the_bytes_one_process_writes(walk, tmp_path, two_cores, monkeypatch, motion):
    """Both runs take the same odometry (its first run replayed): kiss-icp's parallel sums differ in their last
    bits from run to run, and its thread count is fixed by the first registration a process makes."""
    once, recorded = replaying(deskew_job.run_odometry)
    monkeypatch.setattr(deskew_job, "run_odometry", once)
    one = run(walk, tmp_path / "one.bag", False, map=tmp_path / "one.ply", motion=motion)
    two = run(walk, tmp_path / "two.bag", True, map=tmp_path / "two.ply", motion=motion)
    assert one.metrics["writing"] == "after the odometry" and two.metrics["writing"] == BESIDE
    assert (tmp_path / "one.bag").read_bytes() == (tmp_path / "two.bag").read_bytes()
    assert (tmp_path / "one.ply").read_bytes() == (tmp_path / "two.ply").read_bytes()
    assert "helper_peak_rss_mb" not in one.metrics and 20 < two.metrics["helper_peak_rss_mb"] < 2000
    drop = ("time_s", "real_time_factor", "writing", "output", "map", "helper_peak_rss_mb")
    a, b = ({k: v for k, v in r.metrics.items() if k not in drop} for r in (one, two))
    assert a == b
    assert one.metrics["scans"]["deskewed"] == 30 and one.notes == two.notes
    assert len(recorded[0].batches) > 5  # the poses went over in batches as they settled


def _unsigned_time(first: int):
    """An edit giving the clouds from the ``first``-th on their time field as uint32 nanoseconds."""
    def edit(k, arr):
        if k < first:
            return arr
        new = np.empty(len(arr), dtype=[(n, "<u4" if n == "time" else arr.dtype[n]) for n in arr.dtype.names])
        for n in arr.dtype.names:
            new[n] = np.rint(arr[n] * 1e9) if n == "time" else arr[n]
        return new
    return edit


def test_a_bad_cloud_the_helper_meets_is_the_one_line_error_and_nothing_is_written(walk, tmp_path, two_cores,
                                                                                   rewrite_clouds):
    log = rewrite_clouds(walk, tmp_path / "mixed.bag", _unsigned_time(12))
    with pytest.raises(InputError) as err:
        run(log, tmp_path / "out.bag", True, map=tmp_path / "out.ply")
    assert str(err.value) == (f"{log}: /points: the per-point time field 'time' is unsigned, so it cannot hold the "
                              "negative offsets of --reference end (every point before the new header stamp); use "
                              "--reference start")
    with pytest.raises(InputError) as one:
        run(log, tmp_path / "out.bag", False)
    assert str(one.value) == str(err.value)
    assert leftovers(tmp_path, "out") == []


def test_a_failing_odometry_stops_the_helper_and_its_files_go(walk, tmp_path, two_cores, monkeypatch):
    real, helpers = deskew_job.run_odometry, []

    def failing(log, cfg, source, progress, reader, settled):
        seen = []

        def sink(batch):
            if settled is not None:
                settled(batch)
            seen.extend(batch)
            if seen[-1].stamp_ns - seen[0].stamp_ns > 10**9:  # a second of poses went to the helper
                raise ProcessingError("the odometry gave up")

        return real(log, cfg, source, progress, reader, sink)

    start = deskew_helper.Helper.start

    def tracked():
        h = start()
        helpers.append(h)
        return h

    monkeypatch.setattr(deskew_job, "run_odometry", failing)
    monkeypatch.setattr(deskew_job.Helper, "start", staticmethod(tracked))
    with pytest.raises(ProcessingError, match="^the odometry gave up$"):
        run(walk, tmp_path / "out.bag", True, map=tmp_path / "out.ply")
    # ended by the parent: its pipe closed and SIGTERM (exit 1 once its handler is set, else killed by it)
    assert len(helpers) == 1 and helpers[0].proc.returncode in (1, -signal.SIGTERM)
    assert leftovers(tmp_path, "out") == []


def test_a_helper_that_dies_is_a_one_line_error_and_its_temporaries_go(walk, tmp_path, two_cores, monkeypatch):
    """Killed once it has begun its output (it cannot remove it itself)."""
    send, seen = deskew_helper.Helper.send, []

    def killing(self, kind, value):
        if kind == "end":
            for _ in range(200):  # until it has opened its output (it waits for this message to finish it)
                if self.temps:
                    break
                time.sleep(0.05)
            seen.append([p.name for p in self.temps])
            self.proc.kill()
            self.proc.wait()
        send(self, kind, value)

    monkeypatch.setattr(deskew_helper.Helper, "send", killing)
    with pytest.raises(ProcessingError) as err:
        run(walk, tmp_path / "out.bag", True, map=tmp_path / "out.ply")
    assert str(err.value) == "the writing process stopped without an answer (exit code -9)"
    assert len(seen) == 1 and seen[0][0].startswith(".out.bag.")  # the log's temporary existed
    assert leftovers(tmp_path, "out") == []


def test_interrupted_before_the_commit_nothing_is_renamed(walk, tmp_path, two_cores, monkeypatch):
    """The helper has written everything and waits; the parent stops (Ctrl-C) before it says commit."""
    send = deskew_helper.Helper.send

    def interrupted(self, kind, value):
        if kind == "commit":
            raise KeyboardInterrupt
        send(self, kind, value)

    start, helpers = deskew_helper.Helper.start, []
    monkeypatch.setattr(deskew_helper.Helper, "send", interrupted)
    monkeypatch.setattr(deskew_job.Helper, "start", staticmethod(lambda: helpers.append(start()) or helpers[-1]))
    t0 = time.perf_counter()
    with pytest.raises(KeyboardInterrupt):
        run(walk, tmp_path / "out.bag", True, map=tmp_path / "out.ply")
    assert time.perf_counter() - t0 < 30  # not the minute abort() would wait before killing it
    assert helpers[0].proc.returncode == 1  # it discarded its files itself (its SIGTERM handler)
    assert leftovers(tmp_path, "out") == []


def test_a_final_clock_offset_rewrites_after_the_odometry_and_the_helper_s_files_go(walk, tmp_path, two_cores,
                                                                                    monkeypatch):
    """When the odometry's final clock offset disagrees with what it applied, the helper's work is dropped and
    the one-process writer runs with the final offset: the same bytes as without a helper."""
    moved, _ = replaying(deskew_job.run_odometry, lambda r: dataclasses.replace(r, final_offset_ns=2_000_000))
    monkeypatch.setattr(deskew_job, "run_odometry", moved)
    two = run(walk, tmp_path / "two.bag", True, map=tmp_path / "two.ply")
    one = run(walk, tmp_path / "one.bag", False, map=tmp_path / "one.ply")
    assert two.metrics["writing"] == ("after the odometry (the clock offset it measured by its end differs from what "
                                      "it applied online: every scan is written with the final one)")
    assert one.metrics["writing"] == "after the odometry"
    assert (tmp_path / "one.bag").read_bytes() == (tmp_path / "two.bag").read_bytes()
    assert (tmp_path / "one.ply").read_bytes() == (tmp_path / "two.ply").read_bytes()
    assert sorted(p.name for p in tmp_path.iterdir()) == sorted(
        f"{a}.{b}" for a in ("one", "two") for b in ("bag", "ply", "deskew.metrics.json", "deskew.config.yaml"))


@pytest.mark.parametrize("helper", [True, False])
def test_strict_refuses_a_scan_the_odometry_s_poses_do_not_cover(walk, tmp_path, two_cores, helper):
    """Poses 0.1 s apart with a gap limit of 0.05 s: the first sweep is in a gap."""
    with pytest.raises(InputError) as err:
        run(walk, tmp_path / "out.bag", helper, strict=True, **{"trajectory.max_gap_s": 0.05})
    assert re.fullmatch(rf"{re.escape(str(walk))}: /points: the scan of \d+\.\d{{9}} s to \d+\.\d{{9}} s is in a gap of "
                        r"the trajectory \(\d+\.\d{9} s to \d+\.\d{9} s\); without --strict such scans are copied "
                        r"unchanged and counted", str(err.value)), str(err.value)
    assert leftovers(tmp_path, "out") == []


def test_a_single_core_writes_in_one_process(walk, tmp_path, monkeypatch):
    monkeypatch.setattr(deskew_helper, "usable_cpus", lambda: 1)
    assert run(walk, tmp_path / "out.bag", True).metrics["writing"] == "after the odometry"


def test_the_helper_runs_this_lio_cli_from_any_working_directory(tmp_path, monkeypatch):
    """A folder named lio_cli in the working directory is not what the helper imports."""
    (tmp_path / "lio_cli").mkdir()
    (tmp_path / "lio_cli" / "__init__.py").write_text("import sys\nsys.exit(7)\n")  # were it imported
    monkeypatch.chdir(tmp_path)
    monkeypatch.setattr(deskew_helper, "usable_cpus", lambda: 2)
    h = deskew_helper.Helper.start()
    h.proc.stdin.close()  # the helper imports its modules and waits for the setup: EOF, exit 1 (7: wrong one)
    assert h.proc.wait(60) == 1
    h.abort()


@pytest.mark.parametrize("helper", [True, False])
def test_progress_runs_up_to_both_passes_and_never_back(walk, tmp_path, two_cores, helper):
    calls = []
    cfg = DeskewConfig()
    run_deskew(DeskewJob(walk, tmp_path / "out.bag", cfg, helper=helper), lambda d, t: calls.append((d, t)))
    assert {t for _, t in calls} == {60} and calls[-1] == (60, 60)  # 30 scans, two passes
    done = [d for d, _ in calls]
    assert done == sorted(done) and done[:30] == list(range(1, 31))  # the odometry's scans first


def test_a_helper_error_stays_one_line_when_the_parent_ends_it_while_it_answers(walk, tmp_path, two_cores,
                                                                                   monkeypatch, capfd):
    """The helper sends its error and the parent, which has it, ends the helper (SIGTERM) while it is still in
    its error path: its SIGTERM handler raised there, and a 33-line traceback followed the one-line error on
    stderr (a ROS 1 MCAP written as a bag, one run in two)."""
    import subprocess
    import sys

    root = str(Path(deskew_helper.__file__).resolve().parents[3])
    code = f"""
import sys, time
sys.path.insert(0, {root!r})
from lio_cli.errors import InputError
from lio_cli.jobs.deskew import helper as h, write as w
def failing(*args, **kwargs):
    raise InputError("walk.bag: /points: cannot be written")
w.write_pass = failing
send = h._send
def answering_slowly(stream, obj):
    send(stream, obj)
    if obj[0] == "error":
        time.sleep(120)  # still answering when the parent ends it (however slow the machine)
h._send = answering_slowly
h.main()
"""
    helpers = []

    def start():
        proc = subprocess.Popen([sys.executable, "-c", code], stdin=subprocess.PIPE, stdout=subprocess.PIPE)
        helpers.append(deskew_helper.Helper(proc))
        return helpers[-1]

    monkeypatch.setattr(deskew_job.Helper, "start", staticmethod(start))
    capfd.readouterr()
    t0 = time.perf_counter()
    with pytest.raises(InputError) as err:
        run(walk, tmp_path / "out.bag", True)
    assert str(err.value) == "walk.bag: /points: cannot be written"
    assert time.perf_counter() - t0 < 60  # ended, not waited for: a hang fails here
    assert helpers[0].proc.returncode == -signal.SIGTERM  # ended by the parent, never out of its sleep
    assert capfd.readouterr().err == ""
    assert leftovers(tmp_path, "out") == []
