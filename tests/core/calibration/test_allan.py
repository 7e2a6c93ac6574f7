"""Allan deviation and the noise parameters read from it, against the simulator's definitions."""

import re

import numpy as np
import pytest
import yaml

from lio_cli.core.calibration.allan import allan_deviation, estimate_allan
from lio_cli.io.files.kalibr import kalibr_imu_yaml
from lio_cli.plots.allan import allan_plot_png
from lio_cli.errors import InputError
from lio_cli.simulation.motion import Path2D, Progress, Trajectory
from lio_cli.simulation.sensors import ImuSpec, synthesize_imu
from lio_cli.geometry import make_pose, so3_exp

NS = 1_000_000_000
RATE_HZ = 100.0
WHITE_REL_TOL = 0.02  # 3 axes x 180k samples pin a white-noise density to a fraction of a percent
WALK_REL_TOL = 0.2  # 30 min pins the mean of three random walks to ~6% (1-sigma)


@pytest.fixture(scope="module")
def static_log():
    """30 min of a resting IMU (tilted mounting) from the simulator's own noise model, and its spec."""
    spec = ImuSpec(rate_hz=RATE_HZ, gyro_noise_density=2.0e-4, gyro_bias_walk=4.0e-5,
                   accel_noise_density=3.0e-3, accel_bias_walk=6.0e-4)
    still = Trajectory(Path2D(np.array([(0.0, 0.0), (1.0, 0.0), (1.0, 1.0)])), Progress(0.0))
    imu = synthesize_imu(still, make_pose(so3_exp([0.3, -0.2, 1.0])), spec, 0, 1800 * NS, 0, np.random.default_rng(11))
    return imu, spec


def test_white_noise_deviation_falls_as_one_over_sqrt_tau():
    x = np.random.default_rng(2).normal(0.0, 1.0, (200_000, 2))
    taus, adev, counts = allan_deviation(x, 0.01)
    assert taus[0] == pytest.approx(0.01) and counts[0] == 200_000 - 1
    short = taus < 10.0  # enough clusters for 5% statistics
    np.testing.assert_allclose(adev[short] * np.sqrt(taus[short] / 0.01)[:, None], 1.0, rtol=0.05)


def test_densities_and_random_walks_come_back(static_log):
    imu, spec = static_log
    r = estimate_allan(imu.stamps_ns, imu.gyro_radps, imu.accel_mps2)
    assert r.rate_hz == pytest.approx(RATE_HZ)
    np.testing.assert_allclose(r.gyro.noise_density, spec.gyro_noise_density, rtol=WHITE_REL_TOL)
    np.testing.assert_allclose(r.accel.noise_density, spec.accel_noise_density, rtol=WHITE_REL_TOL)
    assert r.gyro.random_walk_mean == pytest.approx(spec.gyro_bias_walk, rel=WALK_REL_TOL)
    assert r.accel.random_walk_mean == pytest.approx(spec.accel_bias_walk, rel=WALK_REL_TOL)
    # the fitted slopes where each term dominates are the textbook ones
    np.testing.assert_allclose(r.gyro.white_slope, -0.5, atol=0.03)
    np.testing.assert_allclose(np.nanmean(r.accel.random_walk_slope), 0.5, atol=0.15)
    # no flicker in the simulator: the minimum is where white noise and walk cross, 2 N K / sqrt(3) in AVAR
    expect_min = np.sqrt(2.0 * spec.gyro_noise_density * spec.gyro_bias_walk / np.sqrt(3.0))
    np.testing.assert_allclose(r.gyro.bias_instability * 0.664, expect_min, rtol=0.15)
    assert any("30 min" in n for n in r.notes)


def test_kalibr_yaml_holds_the_axis_means(static_log):
    imu, _ = static_log
    r = estimate_allan(imu.stamps_ns, imu.gyro_radps, imu.accel_mps2)
    doc = yaml.safe_load(kalibr_imu_yaml(r, rostopic="/sensors/imu"))
    assert doc == {
        "accelerometer_noise_density": pytest.approx(r.accel.noise_density.mean(), rel=1e-6),
        "accelerometer_random_walk": pytest.approx(r.accel.random_walk.mean(), rel=1e-6),
        "gyroscope_noise_density": pytest.approx(r.gyro.noise_density.mean(), rel=1e-6),
        "gyroscope_random_walk": pytest.approx(r.gyro.random_walk.mean(), rel=1e-6),
        "rostopic": "/sensors/imu", "update_rate": 100.0,
    }


def test_plot_is_a_png(static_log):
    imu, _ = static_log
    n = 60_000  # 10 min is plenty for a picture
    r = estimate_allan(imu.stamps_ns[:n], imu.gyro_radps[:n], imu.accel_mps2[:n])
    png = allan_plot_png(r)
    assert png[:8] == b"\x89PNG\r\n\x1a\n" and len(png) > 20_000


def test_too_short_a_log_is_refused():
    stamps = np.arange(200, dtype=np.int64) * 10_000_000
    x = np.random.default_rng(0).normal(size=(200, 3))
    msg = ("IMU log too short for an Allan deviation (2.0 s at 100 Hz): record at least a few minutes, ideally hours, "
           "standing still")
    with pytest.raises(InputError, match=re.escape(msg)):
        estimate_allan(stamps, x, x + [0.0, 0.0, 9.81])


def test_a_log_that_moves_is_flagged(static_log):
    imu, _ = static_log
    n = 60_000
    gyro = imu.gyro_radps[:n].copy()
    gyro[20_000:21_000, 2] += 0.5  # picked up and turned for 10 s
    r = estimate_allan(imu.stamps_ns[:n], gyro, imu.accel_mps2[:n])
    assert r.notes[0] == "the IMU moves during 1.7% of the log: Allan deviation needs a static recording, the values are suspect"
