"""A ground vehicle's IMU roll and pitch from the planar-motion constraint: the gyro's turns about the base z."""

from __future__ import annotations

import numpy as np
import pytest

from lio_cli.core.calibration.ground_plane import estimate_planar_tilt
from lio_cli.errors import InputError
from lio_cli.geometry import so3_exp, so3_log

S = 1_000_000_000


def gyro_of(R_world_base: np.ndarray, dt: float, R_base_imu: np.ndarray, rng, bias=(0.001, -0.002, 0.001)):
    """The IMU's gyro (noise, a bias) on a base whose orientation is sampled every ``dt``."""
    w = np.array([so3_log(R_world_base[k].T @ R_world_base[k + 1]) / dt for k in range(len(R_world_base) - 1)])
    w = np.vstack([w, w[-1]])
    return w @ R_base_imu + rng.normal(0, 0.002, w.shape) + np.asarray(bias)


def car(seed: int, duration_s: float = 20.0, turning: bool = True, sway_deg: float = 0.25):
    """A car turning both ways (heading over 60 deg) with its body's roll and pitch sway."""
    rng = np.random.default_rng(seed)
    dt = 0.005
    t = np.arange(0.0, duration_s, dt)
    rate = (0.35 * np.sin(0.25 * t + seed) + 0.08) if turning else 0.0 * t
    psi = np.cumsum(rate) * dt
    roll = np.radians(sway_deg) * np.sin(1.3 * t + seed)
    pitch = np.radians(0.8 * sway_deg) * np.sin(0.9 * t + 2 * seed)
    R = np.stack([so3_exp(np.array([0.0, 0.0, p])) @ so3_exp(np.array([a, 0.0, 0.0])) @ so3_exp(np.array([0.0, b, 0.0]))
                  for p, a, b in zip(psi, roll, pitch)])
    return (t * S).astype(np.int64) + 5 * S, R, dt, rng


@pytest.mark.parametrize("seed,eps_deg", [(0, (0.8, -0.5)), (1, (-1.5, 0.3)), (2, (0.4, 1.0))])
def test_a_tilted_mounting_comes_out_of_a_drives_turns_within_a_fifth_of_a_degree(seed, eps_deg):
    stamps, R, dt, rng = car(seed)
    R_true = so3_exp(np.radians([180.0, 0.0, 90.0])) @ so3_exp(np.radians([3.0, -20.0, 40.0]))
    gyro = gyro_of(R, dt, R_true, rng)
    eps = np.radians([*eps_deg, 1.0])  # the guess is off by eps (and 1 deg of yaw, which does not matter here)
    res = estimate_planar_tilt(stamps, gyro, R_base_imu=so3_exp(eps) @ R_true)
    err = np.degrees(res.tilt_rad - eps[:2])
    assert np.abs(err).max() < 0.2
    assert (np.abs(err) <= 3 * np.degrees(res.sigma_rad)).all() and np.degrees(res.sigma_rad).max() < 0.15
    assert np.degrees(res.heading_spread_rad) > 60


def test_a_straight_drive_cannot_part_the_tilt_from_the_start():
    stamps, R, dt, rng = car(0, turning=False)
    res = estimate_planar_tilt(stamps, gyro_of(R, dt, np.eye(3), rng), R_base_imu=np.eye(3))
    assert np.degrees(res.sigma_rad).min() > 1.0  # the information says so: not a small number over an error


def test_a_platform_tumbling_about_every_axis_is_not_planar():
    stamps, R, dt, rng = car(0, sway_deg=15.0)
    with pytest.raises(InputError, match=r"^roll and pitch from planar motion: the vertical moves \d+\.\d deg rms in "
                                         r"the base frame \(at most 2\): the platform does not turn about its base z only"):
        estimate_planar_tilt(stamps, gyro_of(R, dt, np.eye(3), rng), R_base_imu=np.eye(3))


def test_too_short_a_gyro_record_is_refused():
    stamps, R, dt, rng = car(0, duration_s=2.0)
    with pytest.raises(InputError, match=r"^roll and pitch from planar motion: 2\.0 s of gyro \(need 5\)"):
        estimate_planar_tilt(stamps, gyro_of(R, dt, np.eye(3), rng), R_base_imu=np.eye(3))


def car_with_wheels(seed: int, sway_deg: float = 0.75, yaw_deg: float = 2.0):
    """``car`` with its wheels (speed, yaw rate) and its IMU's specific force (a bias, noise, a lever arm)."""
    stamps, R, dt, rng = car(seed, sway_deg=sway_deg)
    t = (stamps - stamps[0]) / S
    v = 6.0 + 2.0 * np.sin(0.4 * t + seed)
    psi = np.unwrap(np.arctan2(R[:, 1, 0], R[:, 0, 0]))
    vel = v[:, None] * np.column_stack([np.cos(psi), np.sin(psi), 0 * t])
    r = np.array([0.3, -0.2, 0.1])
    pos_imu = np.cumsum(vel, axis=0) * dt + R @ r
    acc = np.gradient(np.gradient(pos_imu, dt, axis=0), dt, axis=0)
    f_base = np.einsum("nji,nj->ni", R, acc + np.array([0.0, 0.0, 9.81]))
    R_true = so3_exp(np.radians([1.0, -2.0, 30.0]))
    f_imu = f_base @ R_true + np.array([0.04, -0.03, 0.02]) + rng.normal(0, 0.1, f_base.shape)
    gyro = gyro_of(R, dt, R_true, rng)
    w = np.gradient(psi, dt)
    wheels = (stamps[::4], v[::4] + rng.normal(0, 0.02, len(t[::4])), w[::4] + rng.normal(0, 0.005, len(t[::4])))
    return stamps, gyro, f_imu, wheels, R_true, so3_exp(np.radians([0.0, 0.0, yaw_deg]))


@pytest.mark.parametrize("seed", [0, 1])
def test_the_accelerometer_takes_a_strong_sway_out_of_the_tilt(seed):
    stamps, gyro, f, wheels, R_true, yaw = car_with_wheels(seed)
    eps = np.radians([0.6, -0.4, 0.0])
    R_guess = so3_exp(eps) @ yaw @ R_true
    alone = estimate_planar_tilt(stamps, gyro, R_base_imu=R_guess)
    res = estimate_planar_tilt(stamps, gyro, R_base_imu=R_guess, accel_mps2=f, wheels=wheels)
    err = np.degrees(res.tilt_rad - eps[:2])
    assert np.abs(err).max() < 0.1 and (np.abs(err) <= 3 * np.degrees(res.sigma_rad)).all()
    assert res.rms_sway_rad < 0.3 * alone.rms_sway_rad  # the sway is out of the residual
    assert abs(np.degrees(res.yaw_rad) + 2.0) < 0.3 and abs(np.degrees(res.yaw_rad) + 2.0) <= 3 * np.degrees(res.yaw_sigma_rad)
