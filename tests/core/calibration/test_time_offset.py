"""LiDAR-IMU time offset against the simulator's clock offset (sign: added to IMU stamps)."""

import re

import numpy as np
import pytest

from lio_cli.core.calibration.time_offset import estimate_time_offset
from lio_cli.errors import InputError
from lio_cli.geometry import so3_log
from lio_cli.simulation.calibration_inputs import calibration_inputs

OFFSET_TOL_S = 0.0005  # the median goal; these runs land within ~0.1 ms
SIGMA_RANGE_S = (2e-5, 3e-4)  # the 1-sigma of 30 s of handheld motion: ~0.07 ms
ROT_TOL_DEG = 0.5  # the rotation found on the way (rotation.py does better)


def _run(d, **kw):
    return estimate_time_offset(d.lidar_stamps_ns, d.T_world_lidar, d.imu.stamps_ns, d.imu.gyro_radps, **kw)


def _alignment(phi_l: np.ndarray, phi_i: np.ndarray) -> float:
    """One offset's score as the estimate once computed it, one offset at a time: the batched one's oracle."""
    s = np.linalg.svd(phi_i.T @ phi_l, compute_uv=False)
    return float(2.0 * s.sum() / ((phi_l**2).sum() + (phi_i**2).sum()))


def test_offset_of_the_handheld_log(handheld):
    r = _run(handheld)
    assert handheld.imu_time_offset_s == -0.037
    assert r.imu_time_offset_s == pytest.approx(handheld.imu_time_offset_s, abs=OFFSET_TOL_S)
    assert SIGMA_RANGE_S[0] < r.sigma_s < SIGMA_RANGE_S[1]
    err = np.degrees(np.linalg.norm(so3_log(r.R_lidar_imu @ handheld.T_lidar_imu[:3, :3].T)))
    assert err < ROT_TOL_DEG
    assert r.alignment > 0.99 and r.notes == ()


@pytest.mark.parametrize("offset_s", [0.1, -0.1, 0.005])
def test_offsets_of_either_sign(offset_s):
    d = calibration_inputs("handheld", 20.0, seed=7, imu_time_offset_s=offset_s)
    r = _run(d, gyro_bias_radps=d.imu_spec.gyro_bias0_radps)
    assert r.imu_time_offset_s == pytest.approx(offset_s, abs=OFFSET_TOL_S)


def test_bad_registrations_are_left_out(handheld):
    poses = handheld.T_world_lidar.copy()
    poses[100, :3, :3] = poses[100, :3, :3] @ _rz(0.2)  # one scan registered 11 deg off: two intervals hit
    r = estimate_time_offset(handheld.lidar_stamps_ns, poses, handheld.imu.stamps_ns, handheld.imu.gyro_radps)
    assert r.imu_time_offset_s == pytest.approx(handheld.imu_time_offset_s, abs=OFFSET_TOL_S)
    assert r.notes == ("2 scan intervals left out: their rotation disagrees with the gyro's (bad registrations?)",)


def test_no_rotation_is_refused(handheld):
    still = np.repeat(handheld.T_world_lidar[:1], len(handheld.lidar_stamps_ns), axis=0)
    msg = ("too little rotation to time the IMU against the LiDAR: the trajectory turns at most 0.0 deg/s; swing the "
           "sensor back and forth (yaw or roll sweeps of +-30 deg at about 1 Hz) for 10-20 s; on a vehicle, drive a "
           "slalom")
    with pytest.raises(InputError, match=re.escape(msg)):
        estimate_time_offset(handheld.lidar_stamps_ns, still, handheld.imu.stamps_ns, handheld.imu.gyro_radps)


def test_clock_mismatch_is_refused(handheld):
    wall = handheld.imu.stamps_ns + 3600 * 1_000_000_000  # the IMU stamped an hour later
    msg = ("clock mismatch: the IMU and the LiDAR share 0.0 s of time (need 3 s; LiDAR starts -3600.000 s from the "
           "IMU): are they stamped by different clocks?")
    with pytest.raises(InputError, match=re.escape(msg)):
        estimate_time_offset(handheld.lidar_stamps_ns, handheld.T_world_lidar, wall, handheld.imu.gyro_radps)


def test_a_short_log_is_too_short_not_a_clock_mismatch(handheld):
    """2.5 s of a log on one clock: once "clock mismatch: ... are they stamped by different clocks?", which sent
    users to --imu-time-offset (given or not, the same words)."""
    keep = handheld.lidar_stamps_ns < handheld.lidar_stamps_ns[0] + 2_500_000_000
    with pytest.raises(InputError, match=r"^too short: the IMU and the LiDAR trajectory share 2\.[0-9] s \(need 3 s\): "
                                         r"record longer$"):
        estimate_time_offset(handheld.lidar_stamps_ns[keep], handheld.T_world_lidar[keep], handheld.imu.stamps_ns,
                             handheld.imu.gyro_radps)


def test_offset_beyond_the_search_is_refused(handheld):
    msg = ("the IMU-LiDAR time offset lies beyond the +-0.02 s searched (best at the edge): a clock mismatch between "
           "the sensors?")
    with pytest.raises(InputError, match=re.escape(msg)):
        _run(handheld, max_offset_s=0.02)


def _rz(a):
    c, s = np.cos(a), np.sin(a)
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])


@pytest.mark.parametrize("block_rows", [200_000, 1_000])  # one block; blocks of 20-50 offsets, the last partial
def test_the_coarse_grid_in_one_pass_gives_the_bits_of_one_offset_at_a_time(block_rows, monkeypatch):
    from lio_cli.core.calibration import time_offset
    from lio_cli.core.calibration.signals import PiecewiseLinear
    from lio_cli.core.calibration.time_offset import _alignments

    monkeypatch.setattr(time_offset, "GRID_BLOCK_ROWS", block_rows)

    rng = np.random.default_rng(3)
    for _ in range(20):
        m, n = int(rng.integers(300, 700)), int(rng.integers(20, 50))
        t = np.cumsum(rng.uniform(0.004, 0.006, m))
        pl = PiecewiseLinear(t, rng.normal(0.0, 1.0, (m, 3)) * rng.uniform(0.01, 5.0))
        ta = np.sort(rng.uniform(0.3, t[-1] - 0.4, n))
        tb = ta + rng.uniform(0.05, 0.15, n)
        dt = tb - ta
        phi_l = rng.normal(0.0, 0.3, (n, 3))
        grid = np.arange(-0.1, 0.1 + 0.001, 0.002)
        one_by_one = np.array([_alignment(phi_l, pl.interval_mean(ta - d, tb - d) * dt[:, None]) for d in grid])
        assert np.array_equal(_alignments(phi_l, pl, ta, tb, dt, grid), one_by_one)
