"""The odometry passes behind ``lio calibrate``: what each refining pass covers, and that a gyro-primed pass
measures the mounting instead of returning the one it was primed with."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from lio_cli.config.calibrate import CalibrateConfig
from lio_cli.core.calibration import estimate_rotation
from lio_cli.geometry import inv_pose, so3_exp, so3_log
from lio_cli.io.logs.reader import open_log
from lio_cli.io.sensors.stream import read_imu
from lio_cli.jobs.calibrate.passes import FIRST_MIN_NS, PARTIAL_MIN_NS, LidarPass, first_span_ns, pass_until, refine_spans
from lio_cli.simulation.run import simulate

S = 1_000_000_000


def test_passes_before_the_last_cover_a_quarter_of_the_log_but_at_least_ten_seconds():
    assert refine_spans(3, planar=False) == [pytest.approx(1 / 4), pytest.approx(1 / 4), 1.0]
    assert refine_spans(0, planar=False) == []
    assert refine_spans(3, planar=True) == [1.0, 1.0]  # 2D scans: the two fused passes, whole log
    assert pass_until(1 / 4, 0, 60 * S) == 15 * S
    assert pass_until(1 / 4, 0, 21 * S) == PARTIAL_MIN_NS
    assert pass_until(1 / 4, 0, 8 * S) is None  # a short log: every pass covers all of it
    assert pass_until(1.0, 0, 60 * S) is None


def test_the_lidar_only_pass_registers_half_a_long_log_but_at_least_twenty_seconds():
    assert first_span_ns(3, planar=False, duration_ns=60 * S) == 30 * S
    assert first_span_ns(3, planar=False, duration_ns=30 * S) == FIRST_MIN_NS == 20 * S
    assert first_span_ns(3, planar=False, duration_ns=20 * S) is None  # not less than the log: all of it
    assert first_span_ns(0, planar=False, duration_ns=60 * S) is None  # it gives the final estimates itself
    assert first_span_ns(3, planar=True, duration_ns=60 * S) is None  # 2D scans: every pass registers all


def test_a_lidar_only_pass_gathering_the_sensors_registers_only_its_span_but_reads_all_the_imu(walk):
    with open_log(walk.log_path, None) as reader:
        imu = read_imu(reader, "/imu")
        n = reader.topics["/points"].count
        lp = LidarPass(reader, CalibrateConfig(), {"lidar": "/points", "imu": "/imu"}, planar=False)
        traj, arrays = lp.run(gather=True, span_ns=5 * S)
    assert arrays.scans == n and len(arrays.imu) == len(imu)
    assert 49 <= lp.done <= 51 and len(traj.stamps_ns) == lp.done  # 5 s of 10 Hz scans after the first
    assert traj.stamps_ns[-1] - traj.stamps_ns[0] <= 5 * S  # the last scan ends at most 5 s after the first


@pytest.fixture(scope="module")
def walk(tmp_path_factory):
    root = tmp_path_factory.mktemp("passes")
    return simulate("handheld", root / "walk.bag", "ros1", duration_s=16.0, seed=8, columns=512,
                    imu_time_offset_s=0.02, imu_rotation_deg=(5.0, -8.0, 40.0), imu_lever_arm_m=(0.1, -0.1, 0.05),
                    tf_static=False)


def test_a_gyro_primed_pass_measures_the_mounting_rather_than_returning_the_one_it_was_primed_with(walk):
    t = json.loads(Path(walk.truth_path).read_text())
    T_true = inv_pose(np.array(t["T_base_lidar"])) @ np.array(t["T_base_imu"])
    offset = t["imu"]["imu_time_offset_s"]
    bias = np.array(t["imu"]["gyro_bias_mean_radps"])
    primed = T_true.copy()
    primed[:3, :3] = so3_exp(np.radians([0.0, 0.0, 4.0])) @ T_true[:3, :3]  # 4 deg off about the weak axis
    with open_log(walk.log_path, None) as reader:
        imu = read_imu(reader, "/imu")
        lp = LidarPass(reader, CalibrateConfig(), {"lidar": "/points", "imu": "/imu"}, planar=False)
        traj, _ = lp.run((primed, offset, bias))
    assert lp.stats["lidar_only_scans"] == lp.stats["used"] == len(traj.stamps_ns)  # never fused with the IMU
    assert "gyro-primed" in traj.description
    rot = estimate_rotation(traj.stamps_ns, traj.T_world_lidar, imu.stamps_ns, imu.gyro_radps,
                            imu_time_offset_s=offset, gyro_bias_radps=bias)
    err = np.degrees(so3_log(rot.R_lidar_imu @ T_true[:3, :3].T))
    # the mounting it was primed with, 4 deg off, is not what comes back
    assert abs(err[2]) < 1.5, err
    assert np.abs(err[:2]).max() < 0.5, err


def _increment_scatter_deg(stamps_ns, poses, truth_poses, span=10):
    """RMS (x, y, z) of the error of the trajectory's rotation increments over ``span`` scans, against the truth."""
    e = [so3_log((inv_pose(poses[a]) @ poses[a + span])[:3, :3] @ (inv_pose(truth_poses[a]) @ truth_poses[a + span])[:3, :3].T)
         for a in range(len(stamps_ns) - span)]
    return np.degrees(np.sqrt(np.mean(np.square(e), axis=0)))


def test_map_rounds_shrink_the_roll_and_pitch_scatter_and_the_mounting_error(walk):
    from lio_cli.core.calibration.map_refine import refine_poses
    from lio_cli.core.calibration.signals import GyroOrientation
    from lio_cli.jobs.calibrate.map import MAP_VOXEL, SWEEP_VOXEL
    from lio_cli.simulation.deskew_truth import TrueMotion

    t = json.loads(Path(walk.truth_path).read_text())
    T_true = inv_pose(np.array(t["T_base_lidar"])) @ np.array(t["T_base_imu"])
    offset = t["imu"]["imu_time_offset_s"]
    bias = np.array(t["imu"]["gyro_bias_mean_radps"])
    with open_log(walk.log_path, None) as reader:
        imu = read_imu(reader, "/imu")
        lp = LidarPass(reader, CalibrateConfig(), {"lidar": "/points", "imu": "/imu"}, planar=False)
        lp.sweep_voxel = SWEEP_VOXEL
        traj, _ = lp.run((T_true, offset, bias))
    assert set(lp.sweeps) == {int(s) for s in traj.stamps_ns}  # one thinned sweep per pose, keyed by its stamp
    motion = TrueMotion(walk.truth_path)
    truth = motion.poses(traj.stamps_ns) @ motion.T_base_lidar
    gyro = GyroOrientation(imu.stamps_ns, imu.gyro_radps, bias)
    poses = traj.T_world_lidar
    for _ in range(2):
        poses, moved = refine_poses(traj.stamps_ns, poses, lp.sweeps, gyro, T_true[:3, :3], offset,
                                    MAP_VOXEL * lp.voxel_m)
        assert moved > 0.9 * len(poses)
    before = _increment_scatter_deg(traj.stamps_ns, traj.T_world_lidar, truth)
    after = _increment_scatter_deg(traj.stamps_ns, poses, truth)
    assert (after[:2] < 0.5 * before[:2]).all(), (before, after)  # here 0.66 / 0.42 -> 0.19 / 0.13 deg

    def mounting_error(p):
        rot = estimate_rotation(traj.stamps_ns, p, imu.stamps_ns, imu.gyro_radps, imu_time_offset_s=offset)
        return np.linalg.norm(np.degrees(so3_log(rot.R_lidar_imu @ T_true[:3, :3].T)))

    # here 0.25 deg from the pass alone, 0.04 deg after the rounds (primed with the true mounting either way)
    assert mounting_error(poses) < 0.12


def test_the_gyro_primed_passes_gate_is_odom_s_unless_configured():
    from lio_cli.config.odom import OdomConfig
    from lio_cli.core.odometry.tuning import GYRO_PRIOR_GATE_M
    from lio_cli.jobs.calibrate.passes import pass_config

    assert pass_config(CalibrateConfig(), primed=True).registration.gyro_prior_gate_m is None
    assert OdomConfig().registration.gyro_prior_gate_m is None and GYRO_PRIOR_GATE_M == 1.0  # odom's own: 1 m
    cfg = CalibrateConfig.model_validate({"registration": {"gyro_prior_gate_m": 2.5}})
    assert pass_config(cfg, primed=True).registration.gyro_prior_gate_m == 2.5


def test_the_wheel_pass_maps_at_half_the_odometry_s_voxel_unless_configured():
    from lio_cli.jobs.calibrate.passes import wheel_pass_config

    cfg = CalibrateConfig()
    assert wheel_pass_config(cfg, 0.5).registration.voxel_size_m == pytest.approx(0.25)
    assert cfg.registration.voxel_size_m is None  # the configuration itself is left as it was
    assert wheel_pass_config(cfg, None) is cfg  # no odometry voxel known: nothing to halve
    given = CalibrateConfig.model_validate({"registration": {"voxel_size_m": 0.4}})
    assert wheel_pass_config(given, 0.5).registration.voxel_size_m == 0.4


def test_the_wheel_pass_s_finer_map_halves_the_2d_registration_jitter(tmp_path):
    """The wheel scales are fitted against a gyro-primed pass of 2D scans: its error in the distance driven over
    1 s against the ground truth, at the odometry's voxel and at the wheel pass's."""
    from lio_cli.jobs.calibrate.passes import wheel_pass_config

    sim = simulate("planar", tmp_path / "rover.mcap", "mcap", duration_s=10.0, seed=31, tf_static=False)
    t = json.loads(Path(sim.truth_path).read_text())
    T_bl = np.array(t["T_base_lidar"])
    mounting = (inv_pose(T_bl) @ np.array(t["T_base_imu"]), t["imu"]["imu_time_offset_s"],
                np.array(t["imu"]["gyro_bias_mean_radps"]))
    gt = np.loadtxt(sim.gt_path)

    def jitter_cm(traj) -> float:
        p = (traj.T_world_lidar @ inv_pose(T_bl))[:, :2, 3]
        q = np.column_stack([np.interp(traj.stamps_ns * 1e-9, gt[:, 0], gt[:, k]) for k in (1, 2)])
        d = lambda x: np.linalg.norm(x[10:] - x[:-10], axis=1)  # 10 scans: 1 s
        return 100 * float(np.std(d(p) - d(q)))

    topics = {"lidar": "/scan", "imu": "/imu"}
    with open_log(sim.log_path, None) as reader:
        lp = LidarPass(reader, CalibrateConfig(), topics, planar=True)
        coarse = jitter_cm(lp.run(mounting)[0])
        fine = jitter_cm(LidarPass(reader, wheel_pass_config(CalibrateConfig(), lp.voxel_m), topics,
                                   planar=True).run(mounting)[0])
    print(f"1 s distance error std: {coarse:.2f} cm at the odometry's voxel, {fine:.2f} cm at half")
    assert fine < 0.7 * coarse
