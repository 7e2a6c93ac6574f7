"""IMU at rest: still stretch, gyro bias, gravity, accelerometer bias along gravity, noise densities."""

import re

import numpy as np
import pytest

from lio_cli.core.calibration.imu_static import estimate_imu_static, find_still_stretch
from lio_cli.errors import InputError

NS = 1_000_000_000
BIAS_SIGMAS = 4.0  # estimates within this many of their own 1-sigma
DENSITY_REL_TOL = 0.2  # ~1.2 s of 200 Hz data: each density is known to ~5%
UP_TOL_DEG = 0.03  # direction of the mean specific force from 260 samples of 0.03 m/s^2 noise


def _up_imu(d):
    return d.T_base_imu[:3, :3].T @ np.array([0.0, 0.0, 1.0])


def test_standing_start_gives_biases_gravity_and_noise(handheld):
    imu, spec = handheld.imu, handheld.imu_spec
    r = estimate_imu_static(imu.stamps_ns, imu.gyro_radps, imu.accel_mps2)
    t0 = imu.stamps_ns[0]
    # the scenario rests for 1.5 s (true time; the IMU clock runs 37 ms ahead), then eases into motion
    assert 0 <= (r.start_ns - t0) / NS < 0.3 and 1.0 < (r.end_ns - t0) / NS < 1.6
    sel = (imu.stamps_ns >= r.start_ns) & (imu.stamps_ns <= r.end_ns)
    true_bg = imu.gyro_bias_radps[sel].mean(axis=0)
    assert (np.abs(r.gyro_bias_radps - true_bg) < BIAS_SIGMAS * r.gyro_bias_sigma_radps).all()
    # at rest the accelerometer reads gravity plus its bias: horizontal bias components tilt "up"
    f_true = 9.81 * _up_imu(handheld) + imu.accel_bias_mps2[sel].mean(axis=0)
    assert np.degrees(np.arccos(np.clip(r.up_imu @ f_true / np.linalg.norm(f_true), -1, 1))) < UP_TOL_DEG
    true_along = imu.accel_bias_mps2[sel].mean(axis=0) @ _up_imu(handheld)
    assert abs(r.accel_bias_along_gravity_mps2 - true_along) < BIAS_SIGMAS * r.accel_bias_along_gravity_sigma_mps2 + 2e-3
    np.testing.assert_allclose(r.gyro_noise_density, spec.gyro_noise_density, rtol=DENSITY_REL_TOL)
    np.testing.assert_allclose(r.accel_noise_density, spec.accel_noise_density, rtol=DENSITY_REL_TOL)
    assert r.specific_force_norm_mps2 == pytest.approx(np.linalg.norm(f_true), abs=5e-3)


def test_a_given_interval_is_used_as_is_and_flagged_when_it_moves(handheld):
    imu = handheld.imu
    t0 = int(imu.stamps_ns[0])
    still = estimate_imu_static(imu.stamps_ns, imu.gyro_radps, imu.accel_mps2, still_ns=(t0, t0 + NS))
    assert still.samples == 201 and not any("does not look still" in n for n in still.notes)
    moving = estimate_imu_static(imu.stamps_ns, imu.gyro_radps, imu.accel_mps2, still_ns=(t0 + 10 * NS, t0 + 12 * NS))
    assert any("does not look still" in n for n in moving.notes)


def test_no_still_stretch_says_where_the_imu_moves(handheld):
    imu = handheld.imu
    late = imu.stamps_ns >= imu.stamps_ns[0] + 5 * NS  # cut the standing start away
    msg = ("no still stretch of 1 s in the IMU data: it moves during 0.0-25.0 s (s after its first stamp, pauses "
           "shorter than 1 s included; the longest still stretch lasts 0 s); record a few seconds standing still "
           "or name a still interval")
    with pytest.raises(InputError, match=re.escape(msg)):
        find_still_stretch(imu.stamps_ns[late], imu.gyro_radps[late], imu.accel_mps2[late])


def test_short_pauses_do_not_hide_where_the_imu_moves():
    """A vehicle moving to the end with pauses under a second (a real log, robot_localization's test1.bag, read
    "0.9-1.3 s, 1.3-1.3 s, 1.3-1.7 s, 2.3-2.3 s, and 5 more" and hid its 130 s of motion): one range."""
    rate, n = 100, 100 * 60
    stamps = np.arange(n, dtype=np.int64) * (NS // rate)
    t = stamps / NS
    gyro = np.zeros((n, 3))
    accel = np.tile([0.0, 0.0, 9.81], (n, 1))
    moving = (t >= 0.5) & ~((t >= 10.0) & (t < 10.8)) & ~((t >= 20.0) & (t < 20.8)) & ~((t >= 40.0) & (t < 40.8))
    gyro[moving, 2] = 0.5 + 0.3 * np.sin(7.0 * t[moving])
    with pytest.raises(InputError) as err:
        find_still_stretch(stamps, gyro, accel)
    assert "it moves during 0.3-60.0 s (s after" in str(err.value)  # the window of 0.4 s sees it coming
    assert "the longest still stretch lasts 0.2 s" in str(err.value)  # 0.8 s less the window and trims


def test_a_stretch_just_short_of_the_need_is_not_rounded_up_to_it():
    """A pause of 1.57 s (less the window and trims: 0.975 s of stretch) was "the longest still
    stretch lasts 1.0 s" beside "no still stretch of 1 s": now rounded down."""
    rate, n = 100, 100 * 20
    stamps = np.arange(n, dtype=np.int64) * (NS // rate)
    t = stamps / NS
    gyro = np.zeros((n, 3))
    accel = np.tile([0.0, 0.0, 9.81], (n, 1))
    moving = (t >= 0.5) & ~((t >= 10.0) & (t < 11.57))
    gyro[moving, 2] = 0.5 + 0.3 * np.sin(7.0 * t[moving])
    with pytest.raises(InputError) as err:
        find_still_stretch(stamps, gyro, accel)
    assert "the longest still stretch lasts 0.97 s" in str(err.value)


def test_bad_arrays_are_one_line_input_errors():
    stamps = np.arange(0, 50, dtype=np.int64) * 5_000_000
    s = stamps.copy()
    s[3] = s[2] - 5_000_000
    with pytest.raises(InputError, match=re.escape("IMU: stamps must be strictly increasing (sample 3 is 5.000 ms "
                                                   "behind the one before)")):
        estimate_imu_static(s, np.zeros((50, 3)), np.zeros((50, 3)))
    bad = np.zeros((50, 3))
    bad[7, 1] = np.nan
    with pytest.raises(InputError, match=re.escape("IMU gyro: 1 of 50 samples hold NaN or infinite values")):
        estimate_imu_static(stamps, bad, np.zeros((50, 3)))
    with pytest.raises(InputError, match="^no IMU samples$"):
        estimate_imu_static(np.zeros(0, np.int64), np.zeros((0, 3)), np.zeros((0, 3)))
