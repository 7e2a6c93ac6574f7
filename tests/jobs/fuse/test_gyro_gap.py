"""A 10 s IMU dropout on a wheeled robot (the rover, 45 s, seed 7, /imu removed between 20 and 30 s). The planar
filter held the turn rate at its last gyro value while the wheels kept the speed up: the heading turned +42 deg
where the truth turns -6 deg, ATE 3.9 m (0.08 m without the gap). Through the gap the heading now follows the
wheels' yaw rate (their unequal radii's share of the speed, measured against the gyro, taken out), the position
their speed, and the output has poses at the wheel stamps there."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from rosbags.rosbag1 import Reader, Writer

from lio_cli.config.fuse import FuseConfig
from lio_cli.io.files.trajectory import read_tum
from lio_cli.io.sensors.sources import load_trajectory
from lio_cli.jobs.fuse.job import FuseJob, run_fuse
from lio_cli.simulation.run import simulate

from .test_simulated import _ate

GAP_S = (20.0, 30.0)
T0_NS = 1_700_000_000_000_000_000
# measured 1.65 m (the slip at 21-22 s inside the gap turns the wheels 20 deg); held gyro rate 3.9 m, the wheels'
# yaw rate as it is 3.3 m
PLANAR_ATE_M = 2.0
NOTE = ("imu: 1 gap in the gyro (the longest 10.0 s): the heading followed the wheels' yaw rate (499 messages, "
        "their speed's share -0.036 rad/m taken out: unequal radii) and the position the wheels' speed there")


def _without_imu(src: Path, dst: Path, a_s: float, b_s: float) -> None:
    """A copy of a ROS 1 bag without its /imu messages between a_s and b_s after the first message."""
    with Reader(src) as r, Writer(dst) as w:
        conns = {c.id: w.add_connection(c.topic, c.msgtype, msgdef=c.msgdef.data, md5sum=c.digest)
                 for c in r.connections}
        t0 = None
        for c, t, raw in r.messages():
            t0 = t if t0 is None else t0
            if not (c.topic == "/imu" and a_s < (t - t0) * 1e-9 < b_s):
                w.write(conns[c.id], t, raw)


def _rover_with_gap(root: Path, scenario: str = "rover", **kw) -> Path:
    simulate(scenario, root / "full.bag", duration_s=45.0, seed=7, lidar=False, **kw)
    log = root / "gap.bag"
    _without_imu(root / "full.bag", log, *GAP_S)
    (root / "gap.gt.tum").write_text((root / "full.gt.tum").read_text())
    return log


@pytest.fixture(scope="module")
def gap_log(tmp_path_factory) -> Path:
    return _rover_with_gap(tmp_path_factory.mktemp("gyro_gap"))


@pytest.fixture(scope="module")
def good_wheels_gap(tmp_path_factory) -> Path:
    """A car already moving, wheels 3 % large and without slips, the same gap."""
    return _rover_with_gap(tmp_path_factory.mktemp("good_wheels"), "drive", start="moving", wheel_errors=False,
                           wheel_radius_scale=(1.03, 1.03))


def _turn_deg(stamps_ns: np.ndarray, poses: np.ndarray) -> float:
    """The heading's turn from just before the gap to just after it."""
    yaw = np.unwrap(np.arctan2(poses[:, 1, 0], poses[:, 0, 0]))
    a, b = (T0_NS + int(t * 1e9) for t in (GAP_S[0] - 0.1, GAP_S[1] + 0.1))
    return float(np.degrees(np.interp(b, stamps_ns, yaw) - np.interp(a, stamps_ns, yaw)))


def _truth_turn_deg(log: Path) -> float:
    gt = load_trajectory(str(log.with_suffix(".gt.tum")))
    return _turn_deg(gt.stamps_ns, gt.poses)


@pytest.mark.parametrize("smooth", [True, False])
def test_a_gyro_gap_on_wheels_follows_the_wheels_yaw_rate(gap_log, smooth):
    run = run_fuse(FuseJob(gap_log, FuseConfig(smooth=smooth)))
    assert run.metrics["estimator"] == "planar"
    assert _ate(gap_log, run.trajectory) < PLANAR_ATE_M
    assert run.notes.count(NOTE) == 1 and NOTE in run.metrics["notes"], run.notes
    wheel = run.metrics["sources"]["wheel"]
    assert wheel["handled"]["gyro_gap_yaw"]["count"] == 499
    assert wheel["updates_by_kind"]["gyro_gap_yaw_rate"]["updates"] == 499
    # poses through the gap, at the wheel stamps (50 Hz) there
    t = (run.trajectory.stamps_ns - T0_NS) * 1e-9
    inside = t[(t > GAP_S[0] + 0.1) & (t < GAP_S[1] - 0.1)]
    assert len(inside) > 480 and np.diff(inside).max() < 0.021
    assert run.metrics["output"]["stamps"] == ("every IMU sample (exact stamps) and 499 wheel/odometry stamps inside "
                                               "gyro gaps")


def test_the_3d_filter_follows_the_wheels_yaw_rate_through_a_gyro_gap(good_wheels_gap):
    """The 3D filter held the heading across the gap (0 deg where the car turns 92 deg; ATE 41 m); it now turns
    with the wheels' yaw rate, and its velocity with it (measured 91 deg, ATE 2.1 m; the heading alone 16 m)."""
    log = good_wheels_gap
    run = run_fuse(FuseJob(log, FuseConfig(estimator="ekf", smooth=False)))
    assert abs(_turn_deg(run.trajectory.stamps_ns, run.trajectory.poses) - _truth_turn_deg(log)) < 3.0
    assert _ate(log, run.trajectory) < 4.0
    assert ("imu: 1 gap in the gyro (the longest 10.0 s): the heading followed the wheels' yaw rate (499 messages) "
            "and the position the wheels' speed there") in run.notes
    assert run.metrics["sources"]["wheel"]["handled"]["gyro_gap_yaw"]["count"] == 499


def test_the_factor_graph_with_gps_bridges_a_gyro_gap_from_the_wheels_planar_seed(tmp_path):
    """With GPS the factor graph smooths the planar filter's seed: across the gap its IMU factor is the 3D filter's
    increment. Seeded with a held turn rate and the 3D filter's heading held (as before), ATE 0.86 m with the poses
    in the gap; with a decaying turn rate 2.0 m; both following the wheels' yaw rate 0.45 m."""
    log = _rover_with_gap(tmp_path, gps=True)
    run = run_fuse(FuseJob(log, FuseConfig()))
    assert run.metrics["smoother"]["kind"] == "factor_graph" and run.metrics["estimator"] == "planar"
    assert _ate(log, run.trajectory) < 0.7
    assert ("imu: 1 gap in the gyro (the longest 10.0 s): the factor graph took the 3D filter's increment (the "
            "heading following the wheels' yaw rate) and the position the GPS fixes there") in run.notes
    assert "gyro_gap_yaw" not in run.metrics["sources"]["wheel"]["handled"]


def test_wheels_the_gyro_vouched_for_carry_the_heading_through_its_gap(good_wheels_gap):
    """A car already moving, wheels 3 % large without slips: their yaw rate, scale divided out, is used beside the
    gyro. Inside the gap it was left out (unchecked) and the held turn rate made the heading 99 deg off, ATE 46 m;
    the wheels' yaw rate turns it through the gap's 92 deg (measured ATE 0.17 m)."""
    log = good_wheels_gap
    run = run_fuse(FuseJob(log, FuseConfig()))
    assert run.metrics["estimator"] == "planar" and run.metrics["core"]["wheel_yaw_check"]["used"]
    assert _ate(log, run.trajectory) < 0.5
    assert abs(_turn_deg(run.trajectory.stamps_ns, run.trajectory.poses) - _truth_turn_deg(log)) < 3.0
    assert ("imu: 1 gap in the gyro (the longest 10.0 s): the heading followed the wheels' yaw rate (499 messages) "
            "and the position the wheels' speed there") in run.notes
    wheel = run.metrics["sources"]["wheel"]
    assert wheel["handled"]["gyro_gap_yaw"]["count"] == 499
    # the weighing's 503 unchecked less the 499 used inside the gap: 4 at its edges stay out
    assert wheel["rejected"]["yaw_unchecked"]["count"] == 4
    # the weighing's own line says so too, not "503 without the gyro left out"
    assert run.metrics["core"]["wheel_yaw_check"]["why"].endswith(
        ": used beside it, 499 bridging the gyro's gaps, 4 without the gyro left out")


def _yaw_rate_scaled(src: Path, dst: Path, k: float) -> None:
    """A copy of a ROS 1 bag with /wheel/odom's yaw rate times ``k`` (a flipped sign, a deg/s driver)."""
    from rosbags.typesys import Stores, get_typestore

    ts = get_typestore(Stores.ROS1_NOETIC)
    with Reader(src) as r, Writer(dst) as w:
        conns = {c.id: w.add_connection(c.topic, c.msgtype, msgdef=c.msgdef.data, md5sum=c.digest)
                 for c in r.connections}
        for c, t, raw in r.messages():
            if c.topic == "/wheel/odom":
                m = ts.deserialize_ros1(raw, c.msgtype)
                m.twist.twist.angular.z *= k
                raw = ts.serialize_ros1(m, c.msgtype)
            w.write(conns[c.id], t, raw)


@pytest.mark.parametrize("k", [-1.0, 180.0 / np.pi])
def test_a_yaw_rate_the_gyro_refused_never_bridges_its_gap(good_wheels_gap, tmp_path, k):
    """A flipped or deg/s wheel yaw rate, refused beside the gyro (beyond 10 % of its scale), bridged the gap all
    the same: the heading spun (deg/s: -1560 deg in 10 s). Refused, it is left out there too."""
    log = tmp_path / "gap.bag"
    _yaw_rate_scaled(good_wheels_gap, log, k)
    (tmp_path / "gap.gt.tum").write_text(good_wheels_gap.with_suffix(".gt.tum").read_text())
    run = run_fuse(FuseJob(log, FuseConfig(smooth=False)))
    assert "beyond 10%" in run.metrics["core"]["wheel_yaw_check"]["why"]
    assert ("imu: 1 gap in the gyro (the longest 10.0 s): the turn rate decayed to zero (nothing else measures it) "
            "and the position the wheels' speed there") in run.notes
    assert "gyro_gap_yaw" not in run.metrics["sources"]["wheel"]["handled"]
    assert abs(_turn_deg(run.trajectory.stamps_ns, run.trajectory.poses)) < 90.0  # k times the truth's 92: 92, 5300


def test_the_selections_own_yaw_rate_turns_the_3d_filter_through_the_gap(good_wheels_gap):
    """The wheels' yaw rate selected (--use wheel:speed,yaw_rate): the 3D filter rejected it inside the gap as 'in a
    gap of every motion source' and held the heading (0 deg of the car's 92)."""
    run = run_fuse(FuseJob(good_wheels_gap, FuseConfig(estimator="ekf", smooth=False,
                                                       use={"imu": ["gyro", "accel"], "wheel": ["speed", "yaw_rate"]})))
    assert abs(_turn_deg(run.trajectory.stamps_ns, run.trajectory.poses) - _truth_turn_deg(good_wheels_gap)) < 5.0
    wheel = run.metrics["sources"]["wheel"]
    assert wheel["handled"]["gyro_gap_yaw"]["count"] == 499 and "in_gap" not in wheel["rejected"]
    assert ("imu: 1 gap in the gyro (the longest 10.0 s): the heading followed the wheels' yaw rate (499 messages) "
            "and the position the wheels' speed there") in run.notes


def test_a_chunked_run_keeps_what_its_later_chunks_said(tmp_path):
    """Fused in chunks, the notes and the gap's output stamps were the first chunk's alone: a gap in a later
    chunk left its poses in the file but neither the note nor the stamps' count in the metrics."""
    simulate("rover", tmp_path / "full.bag", duration_s=70.0, seed=7, lidar=False)
    log = tmp_path / "gap.bag"
    _without_imu(tmp_path / "full.bag", log, 50.0, 55.0)
    run = run_fuse(FuseJob(log, FuseConfig(max_memory_mb=40.0)))
    assert run.metrics["memory"]["chunks"] >= 2, run.metrics["memory"]
    told = [n for n in run.metrics["notes"] if n.startswith("imu: 1 gap in the gyro (the longest 5.0 s)")]
    assert len(told) == 1 and told[0] in run.notes, run.metrics["notes"]
    n = int(run.metrics["output"]["stamps"].split(" and ")[1].split()[0])
    assert 245 <= n <= 251  # 5 s of 50 Hz wheel stamps, each once (the chunks overlap)
    stamps = run.trajectory.stamps_ns
    assert len(np.unique(stamps)) == len(stamps) == 70 * 200 + 1 - 999 + n  # the IMU's samples left, and the gap's


def test_when_the_graph_is_refused_the_gap_note_is_the_kept_filters(tmp_path, monkeypatch):
    """The factor graph refused (its guard), the planar filter's trajectory kept: the gap's note named the graph
    and the wheel yaw rates the planar filter used there went uncounted."""
    from lio_cli.core.fuse.graph import guard

    monkeypatch.setattr(guard, "verdict", lambda *a, **k: "forced by the test")
    log = _rover_with_gap(tmp_path, gps=True)
    run = run_fuse(FuseJob(log, FuseConfig()))
    assert run.metrics["estimator"] == "planar"
    assert run.metrics["smoother"]["why"].startswith("the factor graph refused by its guard (forced by the test)")
    gap = [n for n in run.notes if n.startswith("imu: 1 gap in the gyro")]
    assert gap == [NOTE], gap
    assert run.metrics["sources"]["wheel"]["handled"]["gyro_gap_yaw"]["count"] == 499


def test_an_imu_gap_longer_than_a_wheel_check_stretch_is_fused(tmp_path, rewrite_messages):
    """The wheel check re-anchors its tilt every 30 s stretch of the IMU's samples; a 50 s gap put two stretches'
    starts on one sample and the empty stretch raised IndexError (a traceback, exit 1)."""
    simulate("rover", tmp_path / "full.bag", duration_s=100.0, seed=7, lidar=False)
    t0 = read_tum(tmp_path / "full.gt.tum")[0][0]
    log = rewrite_messages(tmp_path / "full.bag", tmp_path / "gap.bag", "/imu",
                           lambda ns, msg: None if 25e9 < ns - t0 < 75e9 else msg)
    (tmp_path / "gap.gt.tum").write_bytes((tmp_path / "full.gt.tum").read_bytes())
    run = run_fuse(FuseJob(log, FuseConfig(rate_hz=20.0)))
    assert run.metrics["core"]["wheel_check"] is not None
    assert any(n.startswith("imu: 1 gap in the gyro (the longest 50.0 s)") for n in run.notes), run.notes
