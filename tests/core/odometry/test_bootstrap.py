"""Start-up from LiDAR-only poses: standing still or moving, any IMU mounting (core.bootstrap)."""

import numpy as np
import pytest

from lio_cli.core.odometry.bootstrap import align, lidar_still
from lio_cli.geometry import make_pose, so3_exp, so3_log
from lio_cli.model.calibration import Extrinsics
from lio_cli.model.records import ImuBatch
from lio_cli.simulation import build_scenario
from lio_cli.simulation.sensors import ImuSpec, synthesize_imu

G = 9.81
NS = 10**9
UPSIDE_DOWN_YAWED = make_pose(so3_exp(np.array([np.pi, 0, 0])) @ so3_exp(np.array([0, 0, np.pi / 2])), [0.1, -0.05, 0.2])


def _window(scenario: str, t0_s: float, T_base_imu: np.ndarray, seed: int = 3, pose_noise=(0.01, 0.002),
            gyro_bias=(0.004, -0.003, 0.002), span_s: float = 1.0):
    """LiDAR-only poses at 10 Hz (noisy, in the frame of the first one) and IMU samples over a window."""
    sc = build_scenario(scenario)
    traj = sc.trajectory
    rng = np.random.default_rng(seed)
    stamps = (np.round((t0_s + np.arange(0, span_s + 1e-9, 0.1)) * NS)).astype(np.int64)
    true = traj.poses(stamps * 1e-9)
    first_inv = np.linalg.inv(true[0])
    noisy = []
    for T in true:
        T = first_inv @ T
        T[:3, :3] = T[:3, :3] @ so3_exp(rng.normal(0, pose_noise[1], 3))
        T[:3, 3] += rng.normal(0, pose_noise[0], 3)
        noisy.append(T)
    spec = ImuSpec(gyro_bias0_radps=np.array(gyro_bias), accel_bias0_mps2=np.zeros(3))
    data = synthesize_imu(traj, T_base_imu, spec, stamps[0] - NS // 10, stamps[-1] + NS // 10, 0, rng)
    imu = ImuBatch("imu", data.stamps_ns, data.gyro_radps, data.accel_mps2)
    st = traj.state(np.array([stamps[-1] * 1e-9]))
    v_true = (first_inv[:3, :3] @ st.velocity_mps[0])
    g_true = first_inv[:3, :3] @ np.array([0.0, 0.0, -G])
    return stamps, np.stack(noisy), imu, v_true, g_true


def test_gravity_sharpens_with_the_window_and_is_exact_without_noise():
    for span, noise, limit in ((1.0, (0.0, 0.0), 0.02), (2.0, (0.01, 0.002), 0.3)):
        stamps, poses, imu, v_true, g_true = _window("drive", 12.0, np.eye(4), pose_noise=noise, span_s=span)
        b = align(stamps, poses, imu, Extrinsics(np.eye(4), np.eye(4)), gravity_mps2=G, accel_bias=np.zeros(3))
        tilt = np.degrees(np.arccos(np.clip(b.g_world @ g_true / G**2, -1, 1)))
        assert tilt < limit, (span, tilt)


@pytest.mark.parametrize("scenario, t0_s", [("drive", 12.0), ("handheld", 6.0), ("corridor", 8.0)])
@pytest.mark.parametrize("mount", ["aligned", "upside-down-yawed"])
def test_moving_start_recovers_velocity_gravity_and_gyro_bias(scenario, t0_s, mount):
    T_bi = np.eye(4) if mount == "aligned" else UPSIDE_DOWN_YAWED
    stamps, poses, imu, v_true, g_true = _window(scenario, t0_s, T_bi)
    ext = Extrinsics(T_bi, np.eye(4))
    b = align(stamps, poses, imu, ext, gravity_mps2=G, accel_bias=np.zeros(3))
    assert not b.static and b.reason.startswith("moving start")
    speed = np.linalg.norm(v_true)
    assert speed > 0.5  # the window really is moving
    np.testing.assert_allclose(b.v_world, v_true, atol=0.08 + 0.03 * speed)
    tilt = np.degrees(np.arccos(np.clip(b.g_world @ g_true / G**2, -1, 1)))
    assert tilt < 2.0, tilt  # 1 cm of position noise over a 1 s window: about a degree; the filter refines it
    assert np.linalg.norm(b.gyro_bias - [0.004, -0.003, 0.002]) < 0.004


def test_standing_start_needs_lidar_imu_and_wheels_to_agree():
    stamps, poses, imu, v_true, g_true = _window("drive", 0.2, np.eye(4), pose_noise=(0.0005, 0.0001))
    assert np.linalg.norm(v_true) < 1e-9  # the drive scenario rests for 1.5 s
    ext = Extrinsics(np.eye(4), np.eye(4))
    b = align(stamps, poses, imu, ext, gravity_mps2=G, accel_bias=np.zeros(3))
    assert b.static and b.reason.startswith("standing start")
    np.testing.assert_allclose(b.v_world, 0.0)
    np.testing.assert_allclose(b.gyro_bias, [0.004, -0.003, 0.002], atol=6e-4)  # IMU means: sharp
    moving_wheels = np.full(len(stamps), 1.0)
    b2 = align(stamps, poses, imu, ext, gravity_mps2=G, accel_bias=np.zeros(3), wheel_speeds=moving_wheels)
    assert not b2.static  # wheels that turn overrule a still LiDAR


def test_smooth_constant_velocity_is_not_taken_for_standing_still():
    """A car cruising straight: the IMU alone looks still, the LiDAR does not."""
    sc = build_scenario("drive")
    stamps = np.arange(11, dtype=np.int64) * (NS // 10)
    v = np.array([8.0, 0.0, 0.0])
    poses = np.stack([make_pose(np.eye(3), v * t * 1e-9) for t in stamps])
    t_imu = np.arange(-20, 221, dtype=np.int64) * 5_000_000
    imu = ImuBatch("imu", t_imu, np.zeros((len(t_imu), 3)), np.tile([0.0, 0.0, G], (len(t_imu), 1)))
    assert sc is not None and not lidar_still(poses)
    b = align(stamps, poses, imu, Extrinsics(np.eye(4), np.eye(4)), gravity_mps2=G, accel_bias=np.zeros(3))
    assert not b.static
    np.testing.assert_allclose(b.v_world, v, atol=1e-6)
    np.testing.assert_allclose(b.g_world, [0, 0, -G], atol=1e-6)


def test_registrations_stuck_at_a_standstill_misfit_the_imu():
    """A car cruising at 7.5 m/s whose first LiDAR-only registrations stayed at their standstill guess, then caught
    up: the IMU felt no such stop, and the misfit says so; the true poses fit to registration noise."""
    stamps = np.arange(11, dtype=np.int64) * (NS // 10)
    v = np.array([7.5, 0.0, 0.0])
    t_imu = np.arange(-20, 221, dtype=np.int64) * 5_000_000
    imu = ImuBatch("imu", t_imu, np.zeros((len(t_imu), 3)), np.tile([0.0, 0.0, G], (len(t_imu), 1)))
    ext = Extrinsics(np.eye(4), np.eye(4))
    x_true = v[0] * stamps * 1e-9
    x_stuck = np.concatenate([np.full(8, 0.0) + np.arange(8) * 0.01, x_true[8:] - 4.5])
    fits = {}
    for name, x in (("true", x_true), ("stuck", x_stuck)):
        poses = np.stack([make_pose(np.eye(3), [xi, 0.0, 0.0]) for xi in x])
        fits[name] = align(stamps, poses, imu, ext, gravity_mps2=G, accel_bias=np.zeros(3)).residual_m
    assert fits["true"] < 1e-6 and fits["stuck"] > 0.3, fits


def test_known_gravity_and_bias_are_kept():
    stamps, poses, imu, v_true, g_true = _window("handheld", 6.0, np.eye(4))
    ext = Extrinsics(np.eye(4), np.eye(4))
    b = align(stamps, poses, imu, ext, gravity_mps2=G, accel_bias=np.zeros(3), gyro_bias=np.zeros(3), g_world=g_true)
    np.testing.assert_array_equal(b.g_world, g_true)
    np.testing.assert_array_equal(b.gyro_bias, np.zeros(3))
    assert np.linalg.norm(b.v_world - v_true) < 0.15
    assert np.linalg.norm(so3_log(np.eye(3))) == 0.0
