"""Fusion cases from the simulator: noiseless parts equal the truth; the odometry drift is a random walk."""

from __future__ import annotations

import numpy as np

from lio_cli.geometry import interpolate_poses
from lio_cli.simulation.fusion_case import START_NS, OdomNoise, simulate_case


def test_noiseless_odometry_is_the_truth_and_streams_share_one_clock():
    clean = OdomNoise(position_sigma_m=0.0, rotation_sigma_rad=0.0, drift_yaw_rw=0.0, drift_position_rw=0.0)
    case = simulate_case("drive", 5.0, seed=0, odom=clean, gps_sigma_m=0.0)
    od = case.inputs.odom
    np.testing.assert_allclose(od.poses, case.odom_truth_poses, atol=1e-9)
    np.testing.assert_allclose(od.poses, interpolate_poses(case.truth_stamps_ns, case.truth_poses, od.stamps_ns), atol=1e-9)
    for s in (case.inputs.imu, case.inputs.wheel, od, case.inputs.gps):
        assert s.stamps_ns[0] == START_NS and s.stamps_ns.dtype == np.int64
    np.testing.assert_allclose(case.inputs.gps.position_enu_m, od.poses[::2, :3, 3], atol=1e-9)


def test_odometry_drift_grows_like_a_random_walk():
    n = OdomNoise(position_sigma_m=0.0, rotation_sigma_rad=0.0, drift_yaw_rw=0.0, drift_position_rw=0.01)
    errs = []
    for seed in range(8):
        case = simulate_case("drive", 16.0, seed=seed, wheels=False, odom=n)
        errs.append(np.linalg.norm(case.inputs.odom.poses[:, :3, 3] - case.odom_truth_poses[:, :3, 3], axis=1))
    rms = np.sqrt(np.mean(np.square(errs), axis=0))
    # 3-D position random walk of 0.01 m/sqrt(s): rms 0.01 * sqrt(3 t) after t seconds
    np.testing.assert_allclose(rms[-1], 0.01 * np.sqrt(3 * 16.0), rtol=0.35)
    assert rms[40] < rms[-1]
