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
from lio_cli.io.reader import open_log
from lio_cli.io.stream import read_imu
from lio_cli.jobs.calibrate_passes import PARTIAL_MIN_NS, LidarPass, pass_until, refine_spans
from lio_cli.simulation.run import simulate

S = 1_000_000_000


def test_passes_before_the_last_cover_a_third_of_the_log_but_at_least_ten_seconds():
    assert refine_spans(3, planar=False) == [pytest.approx(1 / 3), pytest.approx(1 / 3), 1.0]
    assert refine_spans(0, planar=False) == []
    assert refine_spans(3, planar=True) == [1.0, 1.0]  # 2D scans: the two fused passes, whole log
    assert pass_until(1 / 3, 0, 60 * S) == 20 * S
    assert pass_until(1 / 3, 0, 21 * S) == PARTIAL_MIN_NS
    assert pass_until(1 / 3, 0, 8 * S) is None  # a short log: every pass covers all of it
    assert pass_until(1.0, 0, 60 * S) is None


@pytest.fixture(scope="module")
def walk(tmp_path_factory):
    root = tmp_path_factory.mktemp("passes")
    return simulate("handheld", root / "walk.bag", "ros1", duration_s=16.0, seed=8, columns=512,
                    imu_time_offset_s=-0.02, imu_rotation_deg=(5.0, -8.0, 40.0), imu_lever_arm_m=(0.1, -0.1, 0.05),
                    tf_static=False)


def test_a_gyro_primed_pass_measures_the_mounting_rather_than_returning_the_one_it_was_primed_with(walk):
    t = json.loads(Path(walk.truth_path).read_text())
    T_true = inv_pose(np.array(t["T_base_lidar"])) @ np.array(t["T_base_imu"])
    offset = -t["imu"]["time_offset_s"]
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
