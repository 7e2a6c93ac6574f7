"""An IMU that writes its accelerations in g (Livox's built-in IMU): found from its first samples and scaled to
m/s^2 by every reader (the stream odom, deskew and calibrate read, the columns fuse reads), and said in the
IMU topic's reason."""

from __future__ import annotations

import numpy as np
import pytest

from lio_cli.io.sensors.imu_units import STANDARD_GRAVITY_MPS2, accel_scale
from lio_cli.io.logs.reader import open_log
from lio_cli.io.sensors.series import read_series
from lio_cli.io.sensors.stream import read_imu
from lio_cli.io.sensors.topics import choose_topic

N = 300  # 3 s at 100 Hz


def _imu_log(logs, fmt: str, unit_g: float):
    """A body swaying and turning (|a| between 4 and 16 m/s^2), its accelerations divided by ``unit_g``."""
    rng = np.random.default_rng(3)
    t = np.arange(N) / 100.0
    accel = np.array([0.0, 0.0, 9.81]) + np.column_stack([6.0 * np.sin(4 * t), 3.0 * np.cos(3 * t), 5.0 * np.sin(5 * t)])
    accel += rng.normal(0, 0.05, accel.shape)
    gyro = np.column_stack([0.5 * np.sin(2 * t), 0.2 * np.cos(t), 3.0 * np.sin(t)])

    def build(w):
        w.add_topic("/imu", "sensor_msgs/msg/Imu")
        for i in range(N):
            stamp = logs.T0_NS + i * 10_000_000
            w.write("/imu", stamp + 1000, w.make.imu(stamp, "imu", gyro[i], accel[i] / unit_g))

    return logs.write(fmt, build), accel


def test_accelerations_in_g_are_scaled_by_every_reader(logs, write_format):
    path, accel = _imu_log(logs, write_format, STANDARD_GRAVITY_MPS2)
    with open_log(path) as log:
        assert accel_scale(log, "/imu")[0] == STANDARD_GRAVITY_MPS2
        np.testing.assert_allclose(read_imu(log, "/imu").accel_mps2, accel, rtol=1e-12)
        np.testing.assert_allclose(read_series(log, ["/imu"])["/imu"].accel_mps2, accel, rtol=1e-12)
        why = choose_topic(log, "imu").why
        assert why.startswith("the only IMU topic; its accelerations are in g, not m/s^2 (median magnitude ")
        assert why.endswith("over its first 200 samples, where gravity reads 9.8 in m/s^2): scaled by 9.80665")
        assert choose_topic(log, "imu", "/imu").why.startswith("asked for with --imu-topic; its accelerations are in g")


@pytest.mark.parametrize("unit_g", [1.0, np.inf], ids=["m/s^2", "no accelerometer"])
def test_other_imus_are_read_as_written(logs, unit_g):
    """m/s^2 in brisk motion (|a| 4-16), and a gyro-only IMU that writes zero accelerations: untouched."""
    path, accel = _imu_log(logs, "ros1", unit_g)
    with open_log(path) as log:
        assert accel_scale(log, "/imu") == (1.0, None)
        assert np.array_equal(read_imu(log, "/imu").accel_mps2, accel / unit_g)
        assert choose_topic(log, "imu").why == "the only IMU topic"
