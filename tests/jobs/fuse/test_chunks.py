"""Memory planning and chunk stitching."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from lio_cli.config.fuse import FuseConfig
from lio_cli.core.fuse import FuseInputs, FuseOptions, FuseResult, ImuSeries, SourceReport, WheelSeries
from lio_cli.geometry import make_pose, so3_exp
from lio_cli.jobs.fuse import FuseJob, run_fuse
from lio_cli.jobs.fuse.chunks import slice_inputs
from lio_cli.jobs.fuse.memory import bytes_per_knot, knot_count, plan
from lio_cli.jobs.fuse.stitch import align_onto, kept_shares, merge_reports, merge_wheel_checks
from lio_cli.simulation.run import simulate

from .test_simulated import _ate

T0 = 1_700_000_000 * 10**9


def _inputs(seconds=100, imu_hz=100, wheel_hz=10):
    st = T0 + np.arange(0, seconds * 10**9 + 1, 10**9 // imu_hz, dtype=np.int64)
    ws = st[:: imu_hz // wheel_hz]
    return FuseInputs(imu=ImuSeries(st, np.zeros((len(st), 3)), np.zeros((len(st), 3))),
                      wheel=WheelSeries(ws, np.ones((len(ws), 3)), np.zeros(len(ws))))


def test_knots_and_bytes():
    inp = _inputs()
    use = {"imu": ["accel", "gyro"], "wheel": ["speed"]}
    assert knot_count(inp, use, None) == 10001 + 1001
    assert knot_count(inp, use, 20.0) == 10001 + 1001  # the IMU samples are held anyway
    gyro = {**use, "imu": ["gyro"]}  # no accelerometer: the RTS pass smooths, holding every knot
    assert bytes_per_knot(FuseOptions(estimator="ekf", smooth=True), gyro) == 65 * 12 * 12
    assert bytes_per_knot(FuseOptions(estimator="ekf", smooth=True), {**gyro, "odom": ["delta"]}) == 65 * 18 * 18
    assert bytes_per_knot(FuseOptions(estimator="ekf"), use) == 1600
    # with the accelerometer the factor graph smooths: its filter pass keeps no RTS record, the graph one chunk
    assert bytes_per_knot(FuseOptions(estimator="ekf", smooth=True), use) == 1600
    assert bytes_per_knot(FuseOptions(estimator="planar", smooth=True), {**use, "gps": ["position"]}) == 1600
    assert bytes_per_knot(FuseOptions(estimator="planar", smooth=True), use) == 3000  # IMU + wheels: planar RTS
    # beside odometry the wheels agree with: the planar RTS pass with the increments' clone
    assert bytes_per_knot(FuseOptions(estimator="planar", smooth=True), {**use, "odom": ["delta"]}) == 5500


def test_plan_keeps_one_chunk_within_budget_and_splits_beyond():
    inp = _inputs()
    use = {"imu": ["gyro"], "wheel": ["speed"]}  # smoothed by the RTS pass (no accelerometer)
    one = plan(inp, FuseOptions(estimator="ekf", smooth=True), use, 1024.0)
    assert len(one.chunks) == 1 and one.chunks[0] == (T0, T0 + 100 * 10**9)
    many = plan(inp, FuseOptions(estimator="ekf", smooth=True), use, 100.0)  # ~103 MB needed
    assert len(many.chunks) > 1 and many.chunks[0][0] == T0 and many.chunks[-1][1] == T0 + 100 * 10**9
    assert all(b == c for (_, b), (c, _) in zip(many.chunks[:-1], many.chunks[1:]))
    per_chunk_mb = (many.chunks[0][1] - many.chunks[0][0] + 2 * many.overlap_ns) * 1e-9 * 110.1 * many.bytes_per_knot / 1e6
    assert per_chunk_mb <= 100.0 * 1.01


def test_slice_keeps_the_samples_in_the_span():
    s = slice_inputs(_inputs(), T0 + 10**9, T0 + 2 * 10**9)
    assert len(s.imu) == 101 and len(s.wheel) == 11 and s.odom is None
    assert s.imu.T_base_imu.shape == (4, 4)


def _result(stamps, poses):
    return FuseResult(np.asarray(stamps, np.int64), poses, None, np.zeros((len(stamps), 3)), "ekf", True, {})


def test_alignment_recovers_a_yaw_and_a_shift():
    st = T0 + np.arange(20) * 10**8
    rng = np.random.default_rng(2)
    poses = np.stack([make_pose(so3_exp(rng.normal(0, 0.3, 3)), rng.normal(0, 5, 3)) for _ in st])
    A_true = make_pose(so3_exp(np.array([0.0, 0.0, 0.7])), np.array([3.0, -2.0, 0.5]))
    prev = _result(st, poses)
    nxt = _result(st, np.linalg.inv(A_true) @ poses)
    A, joined = align_onto(prev, nxt, int(st[10]))
    assert joined
    np.testing.assert_allclose(A, A_true, atol=1e-12)
    A, joined = align_onto(prev, _result(st + 10**10, poses), int(st[10]))
    assert not joined and np.allclose(A[:3, :3], np.eye(3))


def test_merged_reports_add_up():
    a, b = SourceReport(received=3, updates=2), SourceReport(received=4, updates=1)
    a.reject("nan")
    b.reject("nan", 2)
    a.outcome("wheel_velocity", "ok")
    b.outcome("wheel_velocity", "outlier")
    m = merge_reports([{"wheel": a}, {"wheel": b}])["wheel"]
    assert (m.received, m.updates, m.rejected) == (7, 4, {"nan": 3, "outlier": 1})
    assert m.by_kind == {"wheel_velocity": {"updates": 1, "outlier": 1}}


def test_merged_reports_count_each_chunks_kept_share():
    """Two chunks that each fused 100 wheel messages, 60 of them in the span each keeps (40 in the overlap): the
    kept spans' 120 updates, not 200; each chunk's anchor (it ties its own world) counted whole, and its
    rejections (a slip's, a jump's: where they are, not spread) as they are."""
    a, b = SourceReport(received=100, updates=100), SourceReport(received=100, updates=100)
    a.note("anchor")
    b.note("anchor")
    a.reject("outlier", 10)
    st = np.arange(100)
    shares = [kept_shares({"wheel": st}, (0, 60, False)), kept_shares({"wheel": st}, (40, 99, True))]
    assert shares == [{"wheel": 0.6}, {"wheel": 0.6}]
    m = merge_reports([{"wheel": a}, {"wheel": b}], shares)["wheel"]
    assert (m.received, m.updates, m.rejected, m.notes) == (200, 120, {"outlier": 10}, {"anchor": 2})


def test_plan_refuses_a_short_log_over_budget_naming_the_rate_far_above_the_imu():
    import pytest

    from lio_cli.errors import ConfigError

    inp = _inputs(seconds=20)
    use = {"imu": ["accel", "gyro"], "wheel": ["speed"]}
    with pytest.raises(ConfigError) as err:  # it returned one chunk of 3.2 GB: 24 GB RSS at 1e6 Hz, OOM-killed
        plan(inp, FuseOptions(estimator="ekf", rate_hz=1e5), use, 1024.0)
    assert str(err.value) == (
        "fusing needs about 3200 MB, over the memory budget of 1024 MB (--max-memory), and a 20 s log is too short "
        "to fuse in chunks (that needs over 60 s): --rate 100000 Hz is 1000 times the IMU rate of 100 Hz, and poses "
        "between IMU samples carry no measurement of their own: lower --rate to 100 Hz or less, or raise "
        "--max-memory to 3201 (MB) or more")
    assert len(plan(inp, FuseOptions(estimator="ekf", rate_hz=100.0), use, 1024.0).chunks) == 1  # the IMU's own rate: 3.5 MB


def test_plan_refuses_when_even_the_shortest_chunk_is_over_budget():
    import pytest

    from lio_cli.errors import ConfigError

    use = {"imu": ["gyro"], "wheel": ["speed"]}  # smoothed by the RTS pass (no accelerometer)
    with pytest.raises(ConfigError) as err:  # it split into 30 s chunks of 52 MB each
        plan(_inputs(), FuseOptions(estimator="ekf", smooth=True), use, 20.0)
    assert str(err.value) == (
        "fusing needs about 103 MB, over the memory budget of 20 MB (--max-memory), and even the shortest chunk "
        "(30 s plus 10 s of overlap each side) needs 52 MB: fuse --no-smooth or raise --max-memory to 52 (MB) or more")
    fits = plan(_inputs(), FuseOptions(estimator="ekf", smooth=True), use, 52.0)
    assert len(fits.chunks) == 4


def test_a_chunked_run_sums_every_chunks_wheel_check():
    a = {"slips": 2, "windows_s": [[1.0, 2.5], [7.0, 8.0]], "scale": 1.0291, "scale_sigma": 0.001, "bridged": 150,
         "left_in": 0, "verified": True, "scale_applied": True, "why": "x"}
    b = {"slips": 1, "windows_s": [[3.0, 4.0]], "scale": 1.002, "scale_sigma": 0.004, "bridged": 60,
         "left_in": 0, "verified": True, "scale_applied": False, "why": "y"}
    m = merge_wheel_checks([a, None, b])
    assert (m["slips"], m["bridged"], m["scale_applied"], m["per_chunk_scale"]) == (3, 210, True, [1.0291, 1.0])
    assert m["verified"] and m["left_in"] == 0
    assert m["why"] == "checked per chunk (2 of 3): 3 slip(s) bridged by the IMU, wheel scale 1.0291, 1.0000"


def test_a_chunk_whose_scale_was_not_measured_bridged_none_of_its_slips():
    """Its windows were found before the scale fit refused: they stay counted as slips, not as bridged ones, and a
    slip left in elsewhere is named; the run's wheels are then not verified."""
    a = {"slips": 2, "windows_s": [[1.0, 2.5], [7.0, 8.0]], "scale": 1.0291, "scale_sigma": 0.001, "bridged": 150,
         "left_in": 1, "verified": False, "scale_applied": True, "why": "x"}
    b = {"slips": 3, "windows_s": [[3.0, 4.0]] * 3, "scale": 1.03, "scale_sigma": 0.02, "bridged": 0,
         "left_in": 0, "verified": False, "scale_applied": False, "why": "not measured"}
    m = merge_wheel_checks([a, b])
    assert (m["slips"], m["bridged"], m["left_in"], m["verified"]) == (5, 150, 1, False)
    assert m["why"] == "checked per chunk (2 of 2): 1 slip(s) bridged by the IMU, 1 left in, wheel scale 1.0291, 1.0000"


CHUNKED_ATE_RATIO = 1.1  # a run fused in chunks against the same log fused whole


@pytest.fixture(scope="module")
def rover100(tmp_path_factory):
    log = tmp_path_factory.mktemp("chunks100") / "rover.mcap"
    simulate("rover", log, duration_s=100.0, seed=8, lidar=False)
    return log


def test_a_run_fused_in_chunks_is_as_accurate_as_the_whole_log(rover100):
    # each chunk found its start again: a moving one knew no gyro bias (the planar filter cannot measure it) and
    # checked its wheels on its own 30 s (measured 0.135 m whole, 0.974 m in 3 chunks; 0.135 m handed over)
    log = rover100
    whole = run_fuse(FuseJob(log, FuseConfig(rate_hz=20.0)))
    chunked = run_fuse(FuseJob(log, FuseConfig(rate_hz=20.0, max_memory_mb=45.0)))
    assert whole.metrics["memory"]["chunks"] == 1 and chunked.metrics["memory"]["chunks"] == 3, chunked.metrics["memory"]
    a, b = _ate(log, whole.trajectory), _ate(log, chunked.trajectory)
    assert b < CHUNKED_ATE_RATIO * a, (a, b)


@pytest.mark.parametrize("smooth", [True, False])
def test_the_3d_filters_chunks_keep_the_gyro_bias_they_were_handed(rover100, smooth):
    """Handed over at the start-up sigma (0.01 rad/s), the bias a chunk without GPS cannot observe again was
    re-fitted wrongly (0.0019 handed, -0.0036 re-fitted, true 0.0021): 2.75 m in 3 chunks against 0.61 whole
    (--no-smooth 2.03 against 1.05). With the filter's own sigma: 0.14 and 0.13."""
    log = rover100
    cfg = {"estimator": "ekf", "smooth": smooth}
    whole = run_fuse(FuseJob(log, FuseConfig(**cfg)))
    chunked = run_fuse(FuseJob(log, FuseConfig(**cfg, max_memory_mb=22.0)))
    assert chunked.metrics["memory"]["chunks"] == 3, chunked.metrics["memory"]
    a, b = _ate(log, whole.trajectory), _ate(log, chunked.trajectory)
    assert b < CHUNKED_ATE_RATIO * a, (a, b)


GPS_CHUNKED_ATE_RATIO = 1.1  # a log with GPS fused in chunks against the same log fused whole
GPS_USE = {"imu": ["gyro"], "wheel": ["speed"], "gps": ["position"]}  # smoothed by the planar RTS pass: fast
CHUNKED_SHARE = 0.85  # of the whole log's memory estimate: two chunks of the 66 s log below


@pytest.fixture(scope="module")
def rover_gps(tmp_path_factory):
    """A consumer receiver (slow error, a multipath jump, optimistic covariance) whose fixes the whole log finds
    agreeing with the wheels and gyro, fused whole and in two chunks."""
    log = tmp_path_factory.mktemp("rover_gps") / "rover_gps.mcap"
    simulate("rover", log, duration_s=66.0, seed=1, lidar=False, gps=True, gps_model="consumer", imu_rate_hz=50.0)
    cfg = {"use": GPS_USE, "rate_hz": 10.0}
    whole = run_fuse(FuseJob(log, FuseConfig(**cfg)))
    budget = CHUNKED_SHARE * whole.metrics["memory"]["estimate_mb"]
    chunked = run_fuse(FuseJob(log, FuseConfig(**cfg, max_memory_mb=budget)))
    assert chunked.metrics["memory"]["chunks"] == 2, chunked.metrics["memory"]
    return log, whole, chunked


def test_gps_agreement_is_judged_on_the_whole_log(rover_gps):
    # each chunk judged its own fixes, and its chunks were turned onto each other by their yaw difference on the
    # overlap: measured 0.116 m whole, 0.482 m in 2 chunks (seed 2: 0.212 m, 1.049 m)
    log, whole, chunked = rover_gps
    a, b = _ate(log, whole.trajectory), _ate(log, chunked.trajectory)
    assert b < GPS_CHUNKED_ATE_RATIO * a, (a, b)
    assert chunked.metrics["core"]["gps_shape"]["kept"] == whole.metrics["core"]["gps_shape"]["kept"]
    w, c = whole.metrics["core"]["sources"]["gps"]["notes"], chunked.metrics["core"]["sources"]["gps"]["notes"]
    assert (c.get("jumps"), c.get("jump_kept")) == (w.get("jumps"), w.get("jump_kept"))


def test_a_chunked_run_counts_the_updates_of_its_kept_spans_once(rover_gps):
    """Both chunks fused the 20 s of overlap, and both counted it: 4302 wheel updates of 3301 messages."""
    _, whole, chunked = rover_gps
    for src in ("wheel", "gps"):
        w, c = whole.metrics["core"]["sources"][src], chunked.metrics["core"]["sources"][src]
        assert c["received"] == w["received"]
        assert abs(c["updates"] - w["updates"]) <= 0.02 * w["updates"], (src, w["updates"], c["updates"])


def _enu_track(t_s: np.ndarray) -> np.ndarray:
    """(N,4,4) a base driving a slow left curve at 2 m/s in ENU, well away from the origin."""
    yaw = 0.02 * t_s
    poses = np.stack([make_pose(so3_exp(np.array([0.0, 0.0, y])), np.zeros(3)) for y in yaw])
    poses[:, 0, 3] = 300.0 + np.cumsum(np.r_[0.0, 2.0 * np.cos(yaw[:-1]) * np.diff(t_s)])
    poses[:, 1, 3] = -200.0 + np.cumsum(np.r_[0.0, 2.0 * np.sin(yaw[:-1]) * np.diff(t_s)])
    return poses


def test_chunks_that_fused_gps_stay_where_the_fixes_put_them(monkeypatch):
    """Each chunk's track is right in ENU (up to a few cm) but its heading 4 deg off, one way or the other, as the
    heading a consumer receiver gives a minute of track can be (a 300 s log's GPS-fused chunks differed by up to
    14 deg on their overlaps): turned onto the chunk before by their yaw difference on the overlap, the chunks
    ended 13.6 m off. Placed where their fixes put them: neither turned nor moved, the seams faded without a
    jump."""
    from lio_cli.core.fuse import FuseOptions
    from lio_cli.jobs.fuse import chunks

    span_s, rate = 120.0, 10
    st = T0 + np.arange(0, int(span_s * rate) + 1) * (10**9 // rate)
    truth = _enu_track((st - T0) * 1e-9)
    inp = FuseInputs(imu=ImuSeries(st, np.zeros((len(st), 3)), np.zeros((len(st), 3))))
    calls = []

    def fake_fuse(piece, options):  # chunk k: its poses with a heading error of +-4 deg, anchored at the origin
        k = len(calls)
        calls.append(options)
        sel = np.isin(st, piece.imu.stamps_ns)
        poses = truth[sel].copy()
        poses[:, :3, :3] = so3_exp(np.array([0.0, 0.0, np.radians(4.0 * (-1) ** k)])) @ poses[:, :3, :3]
        poses[:, :2, 3] += 0.03 * (-1) ** k
        origin = poses[0, :2, 3].copy()
        poses[:, :3, 3] -= poses[0, :3, 3]
        return FuseResult(st[sel], poses, None, np.zeros((len(poses), 3)), "planar", True, {},
                          {"use": {"imu": ["gyro"], "gps": ["position"]}}, origin)

    monkeypatch.setattr(chunks, "fuse", fake_fuse)
    monkeypatch.setattr(chunks, "judge_gps", lambda inputs, options: None)
    memory = plan(inp, FuseOptions(estimator="ekf", smooth=True), {"imu": ["gyro"]}, 5.0)
    assert len(memory.chunks) >= 3, memory
    res, infos = chunks.fuse_chunked(inp, FuseOptions(estimator="ekf", smooth=True), memory)
    assert all(i["placed_on_fixes"] for i in infos)
    expected = truth[:, :3, 3] - truth[0, :3, 3]
    np.testing.assert_array_equal(res.stamps_ns, st)
    assert np.max(np.abs(res.poses[:, :3, 3] - expected)) < 0.07  # the chunks' own 3 cm each way
    step = np.linalg.norm(np.diff(res.poses[:, :3, 3], axis=0), axis=1)
    assert np.max(np.abs(step - 0.2)) < 0.01  # 2 m/s at 10 Hz: no jump at a seam


def test_a_chunked_run_reports_every_stop_once(tmp_path):
    """Stops in different chunks, one cut by a seam: the metrics hold each once, as the whole log's run does."""
    log = tmp_path / "lights.mcap"
    simulate("drive", log, duration_s=100.0, seed=8, lidar=False, start="moving", stops=((20.0, 6.0), (62.0, 6.0)))
    whole = run_fuse(FuseJob(log, FuseConfig(rate_hz=20.0)))
    chunked = run_fuse(FuseJob(log, FuseConfig(rate_hz=20.0, max_memory_mb=38.0)))
    assert chunked.metrics["memory"]["chunks"] >= 3, chunked.metrics["memory"]
    w, c = whole.metrics["core"]["rest"], chunked.metrics["core"]["rest"]
    assert w["spans"] == c["spans"] == 2
    assert np.allclose(np.array(c["span_ns"]), np.array(w["span_ns"]), atol=0.5e9)


def test_a_chunk_on_the_fixes_after_one_without_them_fades_in(monkeypatch):
    """The middle chunk had no fix (an outage): joined onto the chunk before, it carries its own drift (here a
    10 % scale error, metres by its end); the next chunk is placed on the fixes. It jumped there by the whole
    drift in one step (15.6 m on a rover with a 60 s outage); now the seam fades over the overlap's middle."""
    from lio_cli.core.fuse import FuseOptions
    from lio_cli.jobs.fuse import chunks

    span_s, rate = 120.0, 10
    st = T0 + np.arange(0, int(span_s * rate) + 1) * (10**9 // rate)
    truth = _enu_track((st - T0) * 1e-9)
    inp = FuseInputs(imu=ImuSeries(st, np.zeros((len(st), 3)), np.zeros((len(st), 3))))
    calls = []

    def fake_fuse(piece, options):
        k = len(calls)
        calls.append(options)
        sel = np.isin(st, piece.imu.stamps_ns)
        poses = truth[sel].copy()
        origin = poses[0, :2, 3].copy()
        poses[:, :3, 3] -= poses[0, :3, 3]
        if k == 1:  # no fix: the dead reckoning's scale 10 % off
            poses[:, :3, 3] *= 1.1
            origin = None
        return FuseResult(st[sel], poses, None, np.zeros((len(poses), 3)), "planar", True, {},
                          {"use": {"imu": ["gyro"], "gps": ["position"]}}, origin)

    monkeypatch.setattr(chunks, "fuse", fake_fuse)
    monkeypatch.setattr(chunks, "judge_gps", lambda inputs, options: None)
    memory = plan(inp, FuseOptions(estimator="ekf", smooth=True), {"imu": ["gyro"]}, 5.0)
    res, infos = chunks.fuse_chunked(inp, FuseOptions(estimator="ekf", smooth=True), memory)
    assert [i["placed_on_fixes"] for i in infos][:3] == [True, False, True]
    step = np.linalg.norm(np.diff(res.poses[:, :3, 3], axis=0), axis=1)
    assert np.max(step) < 0.6  # 0.2 m a step at 2 m/s, the drift spread over the fade
