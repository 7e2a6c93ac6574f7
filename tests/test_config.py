"""Configuration and calibration files: defaults, overrides, and one-line errors."""

import pytest

from lio_cli.config import OdomConfig, dump_config, load_calibration, load_config
from lio_cli.errors import ConfigError


def test_defaults_and_round_trip_through_written_yaml(tmp_path):
    cfg = OdomConfig()
    assert (cfg.deskew, cfg.prior, cfg.fusion.method) == ("imu", "imu", "ekf")
    path = tmp_path / "c.yaml"
    path.write_text(dump_config(cfg))
    assert load_config(path) == cfg


def test_yaml_overrides_nested_fields(tmp_path):
    path = tmp_path / "c.yaml"
    path.write_text("fusion:\n  method: complementary\n  alpha: 0.9\nregistration:\n  voxel_size_m: 0.4\n")
    cfg = load_config(path)
    assert (cfg.fusion.method, cfg.fusion.alpha, cfg.registration.voxel_size_m) == ("complementary", 0.9, 0.4)


@pytest.mark.parametrize("text, message", [
    ("fusion:\n  alpha: 1.5\n", "fusion.alpha: Input should be less than or equal to 1"),
    ("deskew: sometimes\n", "deskew: Input should be 'imu', 'constant-velocity' or 'none'"),
    ("unknown_option: 1\n", "unknown_option: Extra inputs are not permitted"),
    ("- a\n- b\n", "config must be a mapping of option: value"),
    ("fusion: [\n", "cannot read config (while parsing a flow node)"),
])
def test_bad_config_is_one_line_naming_file_and_field(tmp_path, text, message):
    path = tmp_path / "c.yaml"
    path.write_text(text)
    with pytest.raises(ConfigError) as err:
        load_config(path)
    assert str(err.value).startswith(f"{path}: {message}")


def test_missing_files(tmp_path):
    with pytest.raises(ConfigError, match="no such config file"):
        load_config(tmp_path / "nope.yaml")
    with pytest.raises(ConfigError, match="no such calibration file"):
        load_calibration(tmp_path / "nope.yaml")


def test_calibration_matrix_shape_is_checked(tmp_path):
    path = tmp_path / "cal.yaml"
    path.write_text("T_base_imu: [[1, 0, 0], [0, 1, 0], [0, 0, 1]]\nimu_time_offset_s: 0.002\n")
    with pytest.raises(ConfigError) as err:
        load_calibration(path)
    assert str(err.value) == f"{path}: T_base_imu must be a 4x4 matrix (4 rows of 4 numbers)"
    path.write_text("imu_time_offset_s: 0.002\n")
    assert load_calibration(path).imu_time_offset_s == 0.002
