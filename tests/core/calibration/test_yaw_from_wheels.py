"""The IMU's mounting yaw from the wheels' accelerations: a vehicle turning about its vertical hides it from the gyro."""

from __future__ import annotations

import numpy as np
import pytest

from lio_cli.core.calibration.yaw_from_wheels import estimate_wheel_yaw, halves_scaled
from lio_cli.errors import InputError
from lio_cli.geometry import so3_exp

S = 1_000_000_000


def drive(seed: int, yaw_deg: float, duration_s: float = 20.0, moving: bool = True, robot: bool = False,
          sway_deg: float = 0.25):
    """Wheel speed / yaw rate of a car (speeding up, braking, turning) and its IMU's specific force, mounted
    rolled, pitched and yawed with a lever arm, a bias, noise and the body's sway leaking gravity."""
    rng = np.random.default_rng(seed)
    t = np.arange(0.0, duration_s, 0.005)
    v = (6.0 + 2.0 * np.sin(0.4 * t + seed)) if moving else 0.0 * t
    w = 0.25 * np.sin(0.3 * t) + 0.1 * np.sin(0.9 * t + 1.0)
    if robot:  # a ground robot: 1 m/s, turning harder
        v, w = v / 6.0, 2.0 * w
    dv, dw = np.gradient(v, t), np.gradient(w, t)
    r = np.array([0.3, -0.2, 0.1])
    a = np.column_stack([dv - w * w * r[0] - dw * r[1], v * w - w * w * r[1] + dw * r[0], np.zeros_like(t)])
    sway = np.radians(sway_deg) * np.sin(0.7 * t + seed)  # the body's roll, in phase with nothing in particular
    c, s = np.cos(sway), np.sin(sway)  # the level frame's acceleration and gravity seen by the rolled body
    f_base = np.column_stack([a[:, 0], c * a[:, 1], -s * a[:, 1]]) + 9.81 * np.column_stack([np.zeros_like(t), s, c])
    R_base_imu = so3_exp(np.radians([2.0, -3.0, yaw_deg]))
    f_imu = f_base @ R_base_imu + rng.normal(0, 0.05, 3) + rng.normal(0, 0.1, (len(t), 3))
    stamps = (t * S).astype(np.int64) + 10 * S
    ws = stamps[::4]  # 50 Hz wheels
    return ws, v[::4] + rng.normal(0, 0.02, len(ws)), w[::4] + rng.normal(0, 0.005, len(ws)), stamps, f_imu, R_base_imu


@pytest.mark.parametrize("seed,robot", [(0, False), (1, False), (2, False), (1, True)])
def test_the_mounting_yaw_comes_from_the_wheels_accelerations_within_a_third_of_a_degree(seed, robot):
    ws, v, w, stamps, f, R_true = drive(seed, 30.0, robot=robot)
    R_guess = so3_exp(np.radians([0.0, 0.0, -30.0])) @ R_true  # roll, pitch right; yaw 30 deg off
    res = estimate_wheel_yaw(ws, v, w, stamps, f, R_base_imu=R_guess)
    R_est = so3_exp(np.array([0.0, 0.0, res.yaw_rad])) @ R_guess
    err = np.degrees(np.arctan2((R_est @ R_true.T)[1, 0], (R_est @ R_true.T)[0, 0]))
    assert abs(err) < 0.3
    assert abs(err) <= 3 * np.degrees(res.sigma_rad) and np.degrees(res.sigma_rad) < 0.6
    assert abs(res.scale - 1.0) < 0.02


def test_a_vehicle_standing_still_shows_no_yaw():
    ws, v, w, stamps, f, R_true = drive(0, 30.0, moving=False)
    with pytest.raises(InputError, match=r"^yaw from the wheels' accelerations: too little acceleration"):
        estimate_wheel_yaw(ws, v * 0, w * 0, stamps, f, R_base_imu=R_true)


def gyro_of(seed: int, stamps: np.ndarray, ws: np.ndarray, w: np.ndarray, R_base_imu: np.ndarray,
            sway_deg: float) -> np.ndarray:
    """The gyro of ``drive``'s IMU: the sway's roll rate and the turn rate (the body rolled by ``sway`` on a
    turning base: R_world_base = Rz(heading) Rx(sway)), with noise."""
    t = (stamps - stamps[0]) / S
    sway = np.radians(sway_deg) * np.sin(0.7 * t + seed)
    roll_rate = np.radians(sway_deg) * 0.7 * np.cos(0.7 * t + seed)
    turn = np.interp(stamps, ws, w)
    om = np.column_stack([roll_rate, turn * np.sin(sway), turn * np.cos(sway)])
    return om @ R_base_imu + np.random.default_rng(seed).normal(0, 0.002, (len(t), 3))


@pytest.mark.parametrize("sway_deg", [0.0, 0.25])
def test_the_sway_model_is_used_only_where_the_gyro_shows_a_sway(sway_deg):
    """A level robot's integrated gyro is noise, which the sway model would only add; a swaying body's gravity
    leak is taken out."""
    ws, v, w, stamps, f, R_true = drive(1, 30.0, robot=True, sway_deg=sway_deg)
    R_guess = so3_exp(np.radians([0.0, 0.0, -30.0])) @ R_true
    res = estimate_wheel_yaw(ws, v, w, stamps, f, R_base_imu=R_guess,
                             gyro_radps=gyro_of(1, stamps, ws, w, R_true, sway_deg))
    dropped = any(n.startswith("no body sway modelled") for n in res.notes)
    assert dropped == (sway_deg == 0.0)
    err = np.degrees(res.yaw_rad) - 30.0
    assert abs(err) < 0.6 and abs(err) <= 3 * np.degrees(res.sigma_rad)


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_the_lever_arm_in_the_plane_comes_with_the_yaw(seed):
    """The IMU 0.3 m ahead and 0.2 m right of the base: the turns' centripetal and tangential accelerations place
    it (a sign flipped would be 0.6 m off in x)."""
    ws, v, w, stamps, f, R_true = drive(seed, 30.0, robot=True)
    res = estimate_wheel_yaw(ws, v, w, stamps, f, R_base_imu=R_true, gyro_radps=gyro_of(seed, stamps, ws, w, R_true, 0.25))
    sigma = np.sqrt(np.diag(res.lever_cov_m2))
    err = res.lever_xy_m - np.array([0.3, -0.2])
    assert (np.abs(err) <= 3 * sigma).all() and (sigma < 0.08).all() and (np.abs(err) < 0.05).all()


def turning_on_a_slope(slope_deg: float, bias_error_radps: float, seed: int = 0, duration_s: float = 30.0):
    """A car (7 m/s, speeding up and braking) turning through 270 deg on a plane tilted ``slope_deg``: the
    slope's gravity turns in the base frame as the heading does. Its gyro's bias is known ``bias_error_radps``
    wrong about the base x and y; IMU 0.3 m ahead and 0.2 m right, noise-free but for the gyro's."""
    t = np.arange(0.0, duration_s, 0.005)
    v = 7.0 + 1.5 * np.sin(0.5 * t)
    w = 0.16 + 0.12 * np.sin(0.35 * t + 0.5)  # heading: about 270 deg over the drive
    dv, dw = np.gradient(v, t), np.gradient(w, t)
    psi = np.cumsum(w) * 0.005
    r = np.array([0.3, -0.2])
    a = np.column_stack([dv - w * w * r[0] - dw * r[1], v * w - w * w * r[1] + dw * r[0], np.zeros_like(t)])
    up_world = so3_exp(np.radians([slope_deg, 0.0, 0.0])).T @ np.array([0.0, 0.0, 1.0])  # T^T e_z
    up = np.einsum("nji,j->ni", so3_exp(np.column_stack([0 * t, 0 * t, psi])), up_world)  # Rz(psi)^T T^T e_z
    f = a + 9.81 * up
    gyro = np.column_stack([0 * t, 0 * t, w]) + np.random.default_rng(seed).normal(0, 0.002, (len(t), 3))
    stamps = (t * S).astype(np.int64) + 10 * S
    return stamps[::4], v[::4], w[::4], stamps, f, gyro, np.array([bias_error_radps, -bias_error_radps, 0.0])


@pytest.mark.parametrize("slope_deg,bias_error", [(1.5, 0.0), (1.5, 0.003), (3.0, -0.003)])
def test_a_tilt_fixed_in_the_world_turns_with_the_heading(slope_deg, bias_error):
    """Sway model in 3D: the slope's leak and the wrong bias's growing tilt follow the heading through 270 deg
    (a tilt error linear in the base frame put this lever arm 1.2 m and the yaw 6.4 deg off)."""
    ws, v, w, stamps, f, gyro, bias = turning_on_a_slope(slope_deg, bias_error)
    res = estimate_wheel_yaw(ws, v, w, stamps, f, R_base_imu=np.eye(3), gyro_radps=gyro, gyro_bias_radps=bias)
    err = res.lever_xy_m - np.array([0.3, -0.2])
    sigma = np.sqrt(np.diag(res.lever_cov_m2))
    assert (np.abs(err) < 0.02).all() and (np.abs(err) <= 3 * sigma).all() and (sigma < 0.03).all()
    assert abs(np.degrees(res.yaw_rad)) < 0.1 and abs(res.scale - 1.0) < 0.005


def test_the_windows_do_not_depend_on_where_the_samples_fall():
    """Every stamp 0.3 ms later on both sides (the same data, the 50 Hz wheels' samples no longer on the windows'
    edges): the same estimate. Means of the samples inside a window were centred up to 10 ms off it, 4-5 cm of
    lever arm at 7.5 m/s."""
    ws, v, w, stamps, f, gyro, bias = turning_on_a_slope(0.0, 0.0)
    out = [estimate_wheel_yaw(ws + d, v, w, stamps + d, f, R_base_imu=np.eye(3), gyro_radps=gyro) for d in (0, 300_000)]
    assert np.abs(out[0].lever_xy_m - out[1].lever_xy_m).max() < 1e-3
    assert abs(out[0].yaw_rad - out[1].yaw_rad) < np.radians(0.005)


def test_halves_further_apart_than_their_sigmas_widen_the_lever_arms_sigma():
    from dataclasses import replace

    ws, v, w, stamps, f, gyro, bias = turning_on_a_slope(0.0, 0.0)
    res = estimate_wheel_yaw(ws, v, w, stamps, f, R_base_imu=np.eye(3), gyro_radps=gyro)
    cov = np.diag([1e-4, 4e-4])  # 1 and 2 cm
    a = replace(res, lever_xy_m=np.array([0.30, -0.20]), lever_cov_m2=np.diag([1e-4, 1e-4]))
    b = replace(res, lever_xy_m=np.array([0.30 + 0.10, -0.20 + 0.01]), lever_cov_m2=np.diag([1e-4, 1e-4]))
    scaled = halves_scaled(cov, a, b)
    # x: 10 cm apart at a combined 1.41 cm: 7.07 times wider; y: 1 cm apart, within their sigmas: unchanged
    assert np.sqrt(np.diag(scaled)) == pytest.approx([0.01 * 0.10 / np.sqrt(2e-4), 0.02], rel=1e-9)


def stop_and_go(seed: int, duration_s: float = 20.0):
    """A ground robot's starts and stops: speed (0-0.5 m/s) and turn rate (+-0.6 rad/s) ramping to new levels
    over 0.4 s every 1.5 s; exact wheels, the IMU (180/0/90, 0.3/-0.2 m) with the simulator's accelerometer noise
    (0.002 m/s^2/sqrt(Hz) at 200 Hz) and a bias."""
    rng = np.random.default_rng(seed)
    t = np.arange(0.0, duration_s, 0.005)
    knots = np.arange(0.0, duration_s + 1.5, 1.5)
    x = (knots[:-1, None] + np.array([0.0, 0.4])).ravel()
    lv, lw = rng.uniform(0.0, 0.5, len(knots)), rng.uniform(-0.6, 0.6, len(knots))
    v = np.interp(t, x, np.column_stack([lv[:-1], lv[1:]]).ravel())
    w = np.interp(t, x, np.column_stack([lw[:-1], lw[1:]]).ravel())
    dv, dw = np.gradient(v, t), np.gradient(w, t)
    r = np.array([0.3, -0.2])
    f_base = np.column_stack([dv - w * w * r[0] - dw * r[1], v * w - w * w * r[1] + dw * r[0], np.full_like(t, 9.81)])
    R_base_imu = so3_exp(np.radians([180.0, 0.0, 90.0]))
    f_imu = f_base @ R_base_imu + np.array([0.02, -0.03, 0.04]) + rng.normal(0, 0.002 * np.sqrt(200.0), (len(t), 3))
    stamps = (t * S).astype(np.int64) + 10 * S
    return stamps[::4], v[::4], w[::4], stamps, f_imu, R_base_imu


def test_a_robots_starts_and_stops_are_not_averaged_away():
    """Windows of 0.5 s (1 s spans) averaged away most of 0.4 s ramps: 0.35 deg rms over 8 such logs, up to 0.67
    deg off; the 0.25 s windows keep them."""
    errs = []
    for seed in range(4):
        ws, v, w, stamps, f, R_true = stop_and_go(seed)
        R_guess = so3_exp(np.radians([0.0, 0.0, -20.0])) @ R_true
        res = estimate_wheel_yaw(ws, v, w, stamps, f, R_base_imu=R_guess)
        M = so3_exp(np.array([0.0, 0.0, res.yaw_rad])) @ R_guess @ R_true.T
        err = np.degrees(np.arctan2(M[1, 0], M[0, 0]))
        assert abs(err) <= 3 * np.degrees(res.sigma_rad) and np.degrees(res.sigma_rad) < 0.2
        errs.append(err)
    assert np.sqrt(np.mean(np.square(errs))) < 0.15


def test_the_tilt_walk_covariance_is_the_pairwise_sum_in_linear_memory():
    """The random walk's covariance summed over steps equals the sum over every pair of windows (min(t_i, t_j)
    and the turn between their headings), for windows in any order."""
    from lio_cli.core.calibration.yaw_from_wheels import GRAVITY_MPS2, _tilt_walk_cov
    rng = np.random.default_rng(3)
    n = 60
    A = rng.normal(size=(2 * n, 10))
    H = A.T @ A
    t, psi = rng.permutation(np.sort(rng.uniform(0.0, 60.0, n))), rng.uniform(-4.0, 4.0, n)
    d = psi[None, :] - psi[:, None]
    mt = np.minimum(t[:, None], t[None, :])
    M = np.empty((n, 2, n, 2))
    M[:, 0, :, 0], M[:, 0, :, 1], M[:, 1, :, 0], M[:, 1, :, 1] = mt * np.cos(d), -mt * np.sin(d), mt * np.sin(d), \
        mt * np.cos(d)
    P = np.linalg.solve(H, A.T)
    pairwise = GRAVITY_MPS2**2 * 1e-6 * (P @ M.reshape(2 * n, 2 * n) @ P.T)
    np.testing.assert_allclose(_tilt_walk_cov(A, H, t, psi, 1e-6), pairwise, rtol=1e-9, atol=1e-12 * abs(pairwise).max())
