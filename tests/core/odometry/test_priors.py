"""A scan's initial guess and de-skew knots."""

import numpy as np
import pytest

from lio_cli.core.odometry.priors import cv_knots, guess, lidar_prior
from lio_cli.core.odometry.state import Track
from lio_cli.geometry import make_pose, so3_exp
from lio_cli.model.records import OdometryRecord

NS = 10**9
EXACT = 1e-12


def _moving_track(dx_m: float = 0.1) -> Track:
    track = Track()
    track.append(NS, np.eye(4))
    track.append(NS + NS // 10, make_pose(np.eye(3), [dx_m, 0.0, 0.0]))
    return track


@pytest.mark.parametrize("prior, x_m", [("constant-velocity", 0.2), ("none", 0.1), ("wheel", 0.1 + 1.0 * 0.1)])
def test_the_guess_follows_the_configured_prior(make_state, prior, x_m):
    o = make_state(prior=prior)
    o.track = _moving_track()
    o.wheel = [OdometryRecord(NS + NS // 10, "odom", "base", None, np.array([1.0, 0.0, 0.0]), np.zeros(3))]
    np.testing.assert_allclose(guess(o, NS + NS // 10, NS + 2 * NS // 10)[:3, 3], [x_m, 0.0, 0.0], atol=EXACT)


def test_the_imu_prior_is_the_state_itself(make_state, still_state):
    o = make_state(use_imu=True)
    o.nav.state = still_state(NS)
    o.nav.state.p = np.array([1.0, 2.0, 3.0])
    np.testing.assert_array_equal(guess(o, 0, NS)[:3, 3], [1.0, 2.0, 3.0])


def test_constant_velocity_knots_run_from_the_last_pose_to_the_guess():
    track = _moving_track()
    target = make_pose(so3_exp(np.array([0.0, 0.0, 0.1])), [0.2, 0.0, 0.0])
    knots, poses = cv_knots("constant-velocity", track, target, NS + NS // 10, NS + 2 * NS // 10)
    assert knots.tolist() == [NS + NS // 10, NS + 2 * NS // 10]
    np.testing.assert_allclose(poses[0], track.last_pose, atol=EXACT)
    np.testing.assert_allclose(poses[1], target, atol=EXACT)
    assert cv_knots("none", track, target, NS, 2 * NS) == (None, None)


def test_a_lidar_only_prior_scales_the_last_motion_to_the_interval(make_state):
    o = make_state(prior="constant-velocity")
    o.track = _moving_track(0.1)  # 1 m/s
    pose, knots, knot_poses, gyro = lidar_prior(o, NS + NS // 10, NS + 3 * NS // 10)  # 0.2 s
    assert not gyro
    np.testing.assert_allclose(pose[:3, 3], [0.3, 0.0, 0.0], atol=1e-9)
    np.testing.assert_allclose(knot_poses[-1], pose, atol=EXACT)


def test_a_lidar_only_prior_with_an_imu_turns_by_the_gyro(make_state, still_imu):
    o = make_state(use_imu=True)
    o.imu_mounted = True
    imu = still_imu(0, 2 * NS)
    imu.gyro_radps[:, 2] = 1.0  # 1 rad/s of yaw
    o.imu.add(imu)
    o.track = _moving_track(0.1)
    pose, knots, knot_poses, gyro = lidar_prior(o, NS + NS // 10, NS + 2 * NS // 10)
    assert gyro and len(knots) > 2  # de-skewed along the propagation
    np.testing.assert_allclose(pose[:3, :3], so3_exp(np.array([0.0, 0.0, 0.1])), atol=1e-9)
    np.testing.assert_allclose(pose[:3, 3], [0.2, 0.0, 0.0], atol=1e-9)  # the last velocity held
    *_, gap_gyro = lidar_prior(o, NS + NS // 10, NS + 2 * NS // 10, imu_gap=True)
    assert not gap_gyro  # over an IMU gap: constant velocity
