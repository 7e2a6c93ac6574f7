"""A ground robot whose IMU is mounted upside down and yawed, 0.5 m off the base, starting in motion: refused
in one line without its extrinsic, and with it (``--calib``) fused to an end point as good as the wheels and
gyro dead-reckoned, far better than the wheels alone."""

from __future__ import annotations

import json

import numpy as np
import pytest

from lio_cli.config.fuse import FuseConfig
from lio_cli.errors import InputError
from lio_cli.evaluation import EvalOptions, evaluate
from lio_cli.io.files.trajectory import read_tum
from lio_cli.jobs.fuse.job import FuseJob, run_fuse
from lio_cli.model.trajectory import Trajectory
from lio_cli.simulation.run import simulate

DR_SLACK_M = 0.1  # the fused end point may miss the truth by the gyro + wheel dead reckoning's miss plus this


@pytest.fixture(scope="module")
def rotated(tmp_path_factory):
    log = tmp_path_factory.mktemp("rotated_imu") / "rot.bag"
    simulate("rover", log, duration_s=40.0, seed=7, start="moving", imu_rotation_deg=(180.0, 0.0, 90.0),
             imu_lever_arm_m=(0.4, 0.2, 0.3), tf_static=False, lidar=False)
    return log


def _end_error(log, run) -> float:
    gst, gpo = read_tum(log.with_name("rot.gt.tum"))
    tr = run.trajectory
    k = np.searchsorted(gst, tr.stamps_ns[[0, -1]])
    T0 = gpo[k[0]]
    true_end = np.linalg.inv(T0) @ gpo[k[1]]  # in the start's frame, as the fused path (yaw zero at the start)
    R0 = tr.poses[0, :3, :3]
    est_end = R0.T @ (tr.poses[-1, :3, 3] - tr.poses[0, :3, 3])
    return float(np.linalg.norm(est_end[:2] - true_end[:2, 3]))


def test_an_imu_with_unknown_rotation_is_refused_naming_its_frame(rotated):
    with pytest.raises(InputError) as err:
        run_fuse(FuseJob(rotated))
    assert str(err.value) == (f"{rotated}: IMU /imu is in frame 'imu' and neither /tf_static nor --calib gives "
                              "T_base_imu (base -> imu); pass --calib with T_base_imu (lio calibrate writes one)")


def test_with_its_extrinsic_the_end_point_is_as_good_as_dead_reckoning(rotated):
    T = json.loads(rotated.with_name("rot.truth.json").read_text())["T_base_imu"]
    calib = {"T_base_imu": T}
    fused = run_fuse(FuseJob(rotated, FuseConfig(calibration=calib, rate_hz=20.0)))
    assert fused.metrics["estimator"] == "planar"
    dr = run_fuse(FuseJob(rotated, FuseConfig(calibration=calib, rate_hz=20.0, estimator="planar",
                                              use={"imu": ["gyro"], "wheel": ["speed"]})))
    wheels = run_fuse(FuseJob(rotated, FuseConfig(rate_hz=20.0, estimator="planar",
                                                  use={"wheel": ["speed", "yaw_rate"]})))
    e_fused, e_dr, e_wheels = (_end_error(rotated, r) for r in (fused, dr, wheels))
    assert e_fused <= e_dr + DR_SLACK_M and e_fused < 0.5 * e_wheels


def test_exact_wheels_beside_a_rotated_offset_imu_are_not_scaled(tmp_path):
    """A car with exact wheels and the IMU upside down, yawed and 0.44 m off the base (given in /tf_static), on a
    drive where the gyro's noise walked the carried pitch so that the accelerometer read the wheel scale 0.2 % off
    1 (3.5 of the residual's sigmas): the scale's sigma holds that walk, so the exact wheels stay as they are and
    the path keeps the exact wheels' accuracy (0.011 m horizontal; 0.142 m with the false scale applied)."""
    log = tmp_path / "car.mcap"
    simulate("drive", log, duration_s=45.0, seed=11, start="still", imu_rotation_deg=(180.0, 0.0, 90.0),
             imu_lever_arm_m=(0.3, -0.2, 0.25), wheel_errors=False, lidar=False)
    run = run_fuse(FuseJob(log))
    check = run.metrics["core"]["wheel_check"]
    assert run.metrics["estimator"] == "planar" and check["verified"]
    assert not check["scale_applied"] and abs(check["scale"] - 1.0) < 3 * check["scale_sigma"]
    gst, gpo = read_tum(log.with_name("car.gt.tum"))
    res = evaluate(Trajectory(gst, gpo, name="gt"), run.trajectory, EvalOptions(max_diff_ns=1_000_000))
    d = res.association.ref.poses[:, :3, 3] - res.est_aligned[:, :3, 3]
    assert float(np.sqrt(np.mean(np.sum(d[:, :2] ** 2, axis=1)))) < 0.03
