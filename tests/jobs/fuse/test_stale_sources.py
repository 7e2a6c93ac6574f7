"""Sources that keep publishing while their content is stale: an IMU orientation frozen at identity (a driver
without an attitude filter; taken as attitude it pinned the heading: 4.3 m ATE on a 45 s rover log whose clean
fusion is 0.084 m), and a GPS receiver repeating its last fix with status FIX (1.85 m; good fixes: 0.095 m).
Both are left out, counted with their reason and told in one line; a real orientation and a clean log are kept."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial.transform import Rotation, Slerp

from lio_cli.config.fuse import FuseConfig
from lio_cli.core.fuse import GpsSeries, PoseSeries, SourceReport, WheelSeries
from lio_cli.core.fuse.gps_quality import MOVING_MPS, drop_stale
from lio_cli.core.fuse.orientation_check import check_orientation
from lio_cli.core.fuse.timeline import prepare
from lio_cli.io.files.trajectory import read_tum
from lio_cli.io.logs.reader import open_log
from lio_cli.jobs.fuse import FuseJob, run_fuse
from lio_cli.jobs.fuse.inputs import gather_sources
from lio_cli.jobs.fuse.job import core_options
from lio_cli.simulation.run import simulate

from .test_gps_antenna import _ate

FREEZE_NS = 20 * 10**9  # the receiver freezes this long after the log's start
CLEAN_ATE_M = 0.25  # measured: 0.084 m without GPS, 0.095 with, 0.105 with the frozen fixes left out


@pytest.fixture(scope="module")
def rover(tmp_path_factory):
    """The fuzzing run's 45 s rover logs (the IMU at the base's axes), without and with GPS: a weaving ground robot
    turning at most 9 deg/s (14 two-second windows turn 12 deg or more)."""
    d = tmp_path_factory.mktemp("stale")
    out = {}
    for name, gps in (("plain", False), ("gps", True)):
        out[name] = d / f"{name}.bag"
        simulate("rover", out[name], duration_s=45.0, seed=7, lidar=False, gps=gps)
    return out


def _identity(cov: float):
    def edit(stamp_ns, msg):
        msg.orientation.x, msg.orientation.y, msg.orientation.z, msg.orientation.w = 0.0, 0.0, 0.0, 1.0
        msg.orientation_covariance = np.eye(3).ravel() * cov
        return msg
    return edit


def _ahrs(gt_path, sigma_deg: float):
    """The true R_world_imu (the IMU at the base's axes) with an AHRS's error: a slow wander and white noise."""
    st, poses = read_tum(gt_path)
    slerp = Slerp((st - st[0]) * 1e-9, Rotation.from_matrix(poses[:, :3, :3]))
    rng, sig, wander = np.random.default_rng(1), np.radians(sigma_deg), np.zeros(3)

    def edit(stamp_ns, msg):
        nonlocal wander
        wander = 0.999 * wander + rng.normal(0.0, 0.045 * sig, 3)
        t = np.clip((stamp_ns - st[0]) * 1e-9, 0.0, (st[-1] - st[0]) * 1e-9)
        q = (slerp([t])[0] * Rotation.from_rotvec(wander + rng.normal(0.0, 0.3 * sig, 3))).as_quat()
        msg.orientation.x, msg.orientation.y, msg.orientation.z, msg.orientation.w = map(float, q)
        msg.orientation_covariance = np.eye(3).ravel() * sig**2
        return msg
    return edit


@pytest.mark.parametrize("cov", [0.0, 0.01])
def test_an_orientation_frozen_at_identity_is_left_out(rover, rewrite_messages, tmp_path, cov):
    src = rover["plain"]
    log = rewrite_messages(src, tmp_path / "ori.bag", "/imu", _identity(cov))
    log.with_name("ori.gt.tum").write_bytes(src.with_name(src.stem + ".gt.tum").read_bytes())
    run = run_fuse(FuseJob(log))
    assert _ate(log, run.trajectory) < CLEAN_ATE_M  # trusted: 4.31 m, 4.79 with covariance 0.01
    imu = run.metrics["sources"]["imu"]
    assert imu["measurements"] == ["accel", "gyro"]
    assert imu["rejected"]["orientation_unfollowed"]["count"] == imu["received"] == 9001
    assert "9001 orientations not following the gyro" in imu["summary"]
    check = run.metrics["imu_orientation_check"]
    assert check["disagreeing"] == check["turning_windows"] >= 5
    assert check["median_error_deg"] == check["median_turn_deg"] > 12.0
    assert (f"IMU orientation left out: it does not follow the gyro ({check['disagreeing']} of "
            f"{check['turning_windows']} 2 s windows turning 12 deg or more disagree, by a median "
            f"{check['median_error_deg']:.1f} deg): a frozen or broken attitude; --use imu:gyro,accel,orientation "
            "forces it in") in run.notes


@pytest.mark.parametrize("sigma_deg", [1.0, 3.0])
def test_an_orientation_that_follows_the_gyro_passes(rover, rewrite_messages, tmp_path, sigma_deg):
    """An AHRS's orientation, three times noisier than a real one's relative error, follows the gyro."""
    src = rover["plain"]
    log = rewrite_messages(src, tmp_path / "ahrs.bag", "/imu", _ahrs(src.with_name("plain.gt.tum"), sigma_deg))
    with open_log(log) as reader:
        sources = gather_sources(reader, FuseConfig())
    assert sources.use["imu"] == ["accel", "gyro", "orientation"] and not sources.checks
    check = check_orientation(sources.inputs.imu)
    assert check.follows and check.windows >= 5 and check.disagree <= 0.25 * check.windows
    assert check.median_error_rad < np.radians(2.0 * sigma_deg)


def _frozen_from(t0_ns: int):
    held = {}

    def edit(stamp_ns, msg):
        if stamp_ns - t0_ns > FREEZE_NS:
            fix = held.setdefault("fix", (msg.latitude, msg.longitude, msg.altitude))
            msg.latitude, msg.longitude, msg.altitude = fix
        return msg
    return edit


def test_a_frozen_gps_fix_is_left_out_while_the_wheels_move(rover, rewrite_messages, tmp_path):
    src = rover["gps"]
    st, poses = read_tum(src.with_name("gps.gt.tum"))
    log = rewrite_messages(src, tmp_path / "frozen.bag", "/gps/fix", _frozen_from(int(st[0])))
    log.with_name("frozen.gt.tum").write_bytes(src.with_name("gps.gt.tum").read_bytes())
    run = run_fuse(FuseJob(log))
    assert _ate(log, run.trajectory) < CLEAN_ATE_M  # trusted: 1.85 m (good fixes: 0.095 m)
    fixes = run.sources.gps
    after = int(np.count_nonzero(fixes.stamps_ns - st[0] > FREEZE_NS))  # valid fixes after the freeze
    speed = np.linalg.norm(np.diff(poses[:, :3, 3], axis=0), axis=1) / (np.diff(st) * 1e-9)
    assert speed[st[1:] - st[0] > FREEZE_NS].min() > 2 * MOVING_MPS  # the rover moves all along
    gps = run.metrics["sources"]["gps"]
    assert after > 50 and gps["rejected"]["stale_fix"]["count"] == after - 1  # the first frozen fix is a real one
    assert f"{after - 1} stale (repeating the fix before)" in gps["summary"]
    assert (f"gps: {after - 1} fixes left out: each repeats the fix before it exactly while the wheels or odometry "
            "move (over 0.2 m/s): a receiver repeating its last position") in run.notes


def test_a_clean_log_has_nothing_stale(rover):
    """Every fix and the (absent) orientation of the clean log as before: nothing checked out, nothing dropped."""
    with open_log(rover["gps"]) as reader:
        sources = gather_sources(reader, FuseConfig())
    assert not sources.checks and not any("left out" in n for n in sources.notes)
    prep = prepare(sources.inputs, core_options(FuseConfig(), sources.use))
    assert "stale_fix" not in prep.reports["gps"].rejected
    assert len(prep.gps) == len(sources.gps.stamps_ns) and not any("gps: " in n for n in prep.notes)


def _fixes(n: int, repeat_from: int) -> GpsSeries:
    p = np.column_stack([np.arange(n, dtype=float), np.zeros(n), np.zeros(n)])
    p[repeat_from:] = p[repeat_from]
    return GpsSeries(np.arange(n, dtype=np.int64) * 10**9, p, np.broadcast_to(np.eye(3), (n, 3, 3)).copy(),
                     np.ones(n, bool))


def _wheels(speed_mps: float) -> WheelSeries:
    t = np.arange(0, 21, dtype=np.int64) * 5 * 10**8
    return WheelSeries(t, np.column_stack([np.full(len(t), speed_mps), np.zeros(len(t)), np.full(len(t), np.nan)]),
                       np.zeros(len(t)))


def test_repeated_fixes_at_rest_or_without_a_motion_source_are_kept():
    """At rest a repeated fix is still the right position (a receiver's static hold); without wheels or odometry
    nothing tells rest from motion."""
    for wheel, odom in ((_wheels(0.0), None), (None, None), (_wheels(0.1), None)):
        rep, notes = SourceReport(), []
        assert len(drop_stale(_fixes(10, 4), wheel, odom, rep, notes)) == 10 and not rep.rejected and not notes
    rep, notes = SourceReport(), []
    kept = drop_stale(_fixes(10, 4), _wheels(1.0), None, rep, notes)
    assert (kept.stamps_ns // 10**9).tolist() == [0, 1, 2, 3, 4]  # the first of the repeated fixes is a real one
    assert rep.rejected == {"stale_fix": 5} and len(notes) == 1
    t = np.arange(0, 11, dtype=np.int64) * 10**9  # odometry alone moving at 1 m/s
    poses = np.broadcast_to(np.eye(4), (11, 4, 4)).copy()
    poses[:, 0, 3] = np.arange(11.0)
    rep = SourceReport()
    assert len(drop_stale(_fixes(10, 4), None, PoseSeries(t, poses), rep, [])) == 5 and rep.rejected["stale_fix"] == 5


@pytest.mark.parametrize("use, kept", [(["imu", "wheel"], False), (["imu:gyro,accel,orientation", "wheel"], True)])
def test_a_bare_use_imu_checks_the_orientation_a_named_one_forces_it(rover, rewrite_messages, tmp_path, capsys, use,
                                                                      kept):
    """A bare --use imu took a frozen orientation unchecked (the check ran on the default selection only)."""
    import json

    from lio_cli.cli.app import main

    src = rover["plain"]
    log = rewrite_messages(src, tmp_path / "ori.bag", "/imu", _identity(0.0))
    argv = ["fuse", str(log), "-o", str(tmp_path / "f.tum"), "--no-smooth", "-q"]
    assert main([*argv, *(a for u in use for a in ("--use", u))]) == 0
    metrics = json.loads((tmp_path / "f.fuse.metrics.json").read_text())
    assert ("orientation" in metrics["sources"]["imu"]["measurements"]) is kept
    assert ("IMU orientation left out: it does not follow the gyro" in capsys.readouterr().err) is not kept
