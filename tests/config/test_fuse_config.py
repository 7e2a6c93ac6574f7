"""``lio fuse``'s configuration: the core's defaults, the --use syntax, one-line errors, YAML round trip."""

from __future__ import annotations

import dataclasses

import pytest

from lio_cli.config import dump_model, load_model
from lio_cli.config.fuse import MEASUREMENTS, FuseConfig, parse_use
from lio_cli.core.fuse import MEASUREMENTS as CORE_MEASUREMENTS
from lio_cli.core.fuse import FuseOptions, NoiseOptions
from lio_cli.errors import ConfigError
from lio_cli.jobs.fuse.job import core_options


def test_defaults_are_the_cores():
    """config sits below core, so the numbers are repeated there: they must stay the core's."""
    assert MEASUREMENTS == CORE_MEASUREMENTS
    lidar_odometry = {"odom_position_sigma_m": 0.1, "odom_rotation_sigma_rad": 0.02}  # the one deliberate change
    core = FuseOptions(smooth=True, noise=NoiseOptions(**lidar_odometry))  # lio fuse smooths, the core's default filters
    assert core_options(FuseConfig(), None, covariance=True) == core
    assert {**dataclasses.asdict(NoiseOptions()), **lidar_odometry} == FuseConfig().noise.model_dump()


def test_use_syntax():
    assert parse_use(["imu:gyro,accel", "wheel", "gps:position", "imu:orientation"]) == {
        "imu": ["accel", "gyro", "orientation"], "wheel": ["speed"], "gps": ["position"]}
    # a bare wheel without the gyro turns by its own yaw rate (speed alone drew a straight line)
    assert parse_use(["wheel"]) == {"wheel": ["speed", "yaw_rate"]}
    assert parse_use(["imu:accel", "wheel", "gps"]) == {"imu": ["accel"], "wheel": ["speed", "yaw_rate"],
                                                        "gps": ["position"]}
    assert parse_use(["wheel:speed"]) == {"wheel": ["speed"]}  # named: as named
    with pytest.raises(ConfigError) as err:
        parse_use(["lidar:points"])
    assert str(err.value) == "--use lidar:points: unknown source 'lidar' (choose from imu, wheel, odom, gps)"


@pytest.mark.parametrize("text, message", [
    ("rate_hz: 0\n", "rate_hz: must be a positive number of Hz, got 0.0"),
    ("rate_hz: -5\n", "rate_hz: must be a positive number of Hz, got -5.0"),
    ("use:\n  wheel: [odometer]\n", "use: unknown wheel measurement 'odometer' (choose from speed, velocity, yaw_rate)"),
    ("use:\n  lidar: [points]\n", "use.lidar.[key]: Input should be 'imu', 'wheel', 'odom' or 'gps'"),
    ("estimator: ukf\n", "estimator: Input should be 'auto', 'ekf', 'planar' or 'complementary'"),
    ("input:\n  odom_topic: /a\n  odom_file: b.tum\n", "input: give the odometry as odom_topic or odom_file, not both"),
    ("noise:\n  gyro_noise_density: 0\n", "noise.gyro_noise_density: must be > 0, got 0"),
])
def test_bad_config_is_one_line_naming_the_field(tmp_path, text, message):
    path = tmp_path / "c.yaml"
    path.write_text(text)
    with pytest.raises(ConfigError) as err:
        load_model(FuseConfig, path)
    assert str(err.value) == f"{path}: {message}"


def test_round_trip_through_the_written_yaml(tmp_path):
    cfg = FuseConfig(use={"imu": ["gyro"], "wheel": ["yaw_rate", "speed"]}, estimator="planar", smooth=True,
                     rate_hz=50.0, input={"gps_origin": [47.0, 8.0, 400.0], "wheel_twist_frame": "parent"})
    path = tmp_path / "c.yaml"
    path.write_text(dump_model(cfg))
    assert load_model(FuseConfig, path) == cfg
    assert cfg.use == {"imu": ["gyro"], "wheel": ["speed", "yaw_rate"]}
