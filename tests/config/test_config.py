"""Configuration and calibration files: defaults, overrides field by field, and one-line errors."""

import pytest

from lio_cli.config import dump_model, load_calibration, load_model, with_overrides
from lio_cli.config.odom import OdomConfig
from lio_cli.errors import ConfigError


def test_defaults_and_round_trip_through_written_yaml(tmp_path):
    cfg = OdomConfig()
    assert (cfg.deskew, cfg.prior, cfg.fusion.method) == ("auto", "imu", "ekf")
    assert cfg.input.lidar_topic is None and cfg.calibration.T_base_imu is None
    path = tmp_path / "c.yaml"
    path.write_text(dump_model(cfg))
    assert load_model(OdomConfig, path) == cfg


def test_yaml_overrides_nested_fields(tmp_path):
    path = tmp_path / "c.yaml"
    path.write_text("fusion:\n  method: complementary\n  alpha: 0.9\nregistration:\n  voxel_size_m: 0.4\n"
                    "input:\n  imu_topic: /imu/data\n")
    cfg = load_model(OdomConfig, path)
    assert (cfg.fusion.method, cfg.fusion.alpha, cfg.registration.voxel_size_m) == ("complementary", 0.9, 0.4)
    assert cfg.input.imu_topic == "/imu/data"


def test_flags_override_one_field_each_and_never_another():
    base = OdomConfig().model_copy(update={"deskew": "imu"})
    cfg = with_overrides(base, {"prior": "constant-velocity", "fusion.alpha": 0.5, "input.lidar_topic": "/p",
                                "frame": None})
    assert (cfg.prior, cfg.fusion.alpha, cfg.input.lidar_topic) == ("constant-velocity", 0.5, "/p")
    assert cfg.deskew == "imu"  # untouched by the prior flag: no hidden rule
    assert cfg.frame == "base" and cfg.fusion.method == "ekf"


@pytest.mark.parametrize("prior, deskew", [("imu", "imu"), ("constant-velocity", "constant-velocity"),
                                           ("wheel", "constant-velocity"), ("none", "none")])
def test_auto_deskew_follows_the_prior(prior, deskew):
    assert OdomConfig(prior=prior).resolved_deskew() == deskew
    assert OdomConfig(prior=prior, deskew="imu").resolved_deskew() == "imu"


@pytest.mark.parametrize("text, message", [
    ("fusion:\n  alpha: 1.5\n", "fusion.alpha: must be within [0, 1], got 1.5"),
    ("deskew: sometimes\n", "deskew: Input should be 'auto', 'imu', 'constant-velocity' or 'none'"),
    ("unknown_option: 1\n", "unknown_option: Extra inputs are not permitted"),
    ("input:\n  lidar: /points\n", "input.lidar: Extra inputs are not permitted"),
    ("- a\n- b\n", "config must be a mapping of option: value"),
    ("fusion: [\n", "cannot read config (while parsing a flow node)"),
])
def test_bad_config_is_one_line_naming_file_and_field(tmp_path, text, message):
    path = tmp_path / "c.yaml"
    path.write_text(text)
    with pytest.raises(ConfigError) as err:
        load_model(OdomConfig, path)
    assert str(err.value).startswith(f"{path}: {message}")


def test_missing_files(tmp_path):
    with pytest.raises(ConfigError, match="no such config file"):
        load_model(OdomConfig, tmp_path / "nope.yaml")
    with pytest.raises(ConfigError, match="no such calibration file"):
        load_calibration(tmp_path / "nope.yaml")


@pytest.mark.parametrize("text, message", [
    ("T_base_imu: [[1, 0, 0], [0, 1, 0], [0, 0, 1]]\n", "T_base_imu: must be a 4x4 matrix (4 rows of 4 numbers)"),
    ("T_base_lidar: [[2, 0, 0, 0], [0, 1, 0, 0], [0, 0, 1, 0], [0, 0, 0, 1]]\n",
     "T_base_lidar: is not a rigid transform (rotation block not orthonormal or last row not 0 0 0 1)"),
    ("T_base_lidar: [[1, 0, 0, .nan], [0, 1, 0, 0], [0, 0, 1, 0], [0, 0, 0, 1]]\n", "T_base_lidar: holds a non-finite number"),
    ("imu_time_offset_s: 1.0e12\n", "imu_time_offset_s: must be a finite number of seconds within +-4e+09"),
    ("imu_time_offset_s: .inf\n", "imu_time_offset_s: must be a finite number of seconds within +-4e+09"),
    ("gyro_bias_radps: [0.1, 0.2]\n", "gyro_bias_radps: must be 3 finite numbers (x, y, z in the IMU frame)"),
    # each value within physical bounds, the range named (issue 32)
    ("wheel: {speed_scale: .inf, speed_scale_sigma: 0, yaw_rate_scale: 1, yaw_rate_scale_sigma: 0}\n",
     "wheel.speed_scale: must be within (0, 10], got inf"),
    ("imu_time_offset_sigma_s: .inf\n", "imu_time_offset_sigma_s: must be within [0, 10], got inf"),
    ("imu_time_offset_sigma_s: -0.1\n", "imu_time_offset_sigma_s: must be within [0, 10], got -0.1"),
    ("gyro_bias_sigma_radps: [0.01, -0.01, 0]\n", "gyro_bias_sigma_radps: each value must be within [0, 1] rad/s, got -0.01"),
    ("T_base_imu_rotation_sigma_rad: [-0.1, 0, 0]\n",
     "T_base_imu_rotation_sigma_rad: each value must be within [0, 6.283] rad, got -0.1"),
    ("imu_noise: {gyro_noise_radps: 1.0e+300}\n", "imu_noise.gyro_noise_radps: must be within [0, 1], got 1e+300"),
    ("imu_noise: {accel_bias_walk: 1.0e+300}\n", "imu_noise.accel_bias_walk: must be within [0, 10], got 1e+300"),
    ("T_base_imu: [[1, 0, 0, 1.0e+300], [0, 1, 0, 0], [0, 0, 1, 0], [0, 0, 0, 1]]\n",
     "T_base_imu: translation must be within [-100, 100] m on each axis, got 1e+300 m"),
    ("accel_bias_mps2: [1.0e+6, 0, 0]\n", "accel_bias_mps2: each value must be within [-5, 5] m/s^2, got 1e+06"),
])
def test_calibration_fields_are_checked(tmp_path, text, message):
    path = tmp_path / "cal.yaml"
    path.write_text(text)
    with pytest.raises(ConfigError) as err:
        load_calibration(path)
    assert str(err.value) == f"{path}: {message}"


def test_calibration_values_load(tmp_path):
    path = tmp_path / "cal.yaml"
    path.write_text("imu_time_offset_s: 0.002\nT_base_imu: [[0, -1, 0, 0.1], [1, 0, 0, 0], [0, 0, 1, 0], [0, 0, 0, 1]]\n")
    cal = load_calibration(path)
    assert cal.imu_time_offset_s == 0.002 and cal.imu_time_offset_ns == 2_000_000
    assert cal.matrix("T_base_imu")[0, 3] == 0.1 and cal.matrix("T_base_lidar") is None


def test_calibrate_takes_the_clock_offset_its_clock_check_suggests_even_between_epoch_and_boot_clocks():
    """An Ouster driver stamps its IMU from boot and its clouds from the epoch: the clock check's suggestion,
    --imu-time-offset 1588073416.120, was refused by calibrate's size limit (1e9) though --calib takes it.
    The clock offset alone is bounded by what int64 stamps hold; every other number keeps the limit."""
    from lio_cli.config.calibrate import CalibrateConfig

    assert CalibrateConfig(imu_time_offset_s=1588073416.120).start_offset_ns == 1588073416120000000
    with pytest.raises(ValueError, match="less than or equal to 4000000000"):
        CalibrateConfig(imu_time_offset_s=5e9)
    with pytest.raises(ValueError, match=r"max_offset_s\n.*less than or equal to 5"):
        CalibrateConfig(max_offset_s=2e9)
    with pytest.raises(ValueError, match=r"1e\+10 is out of range \(\|value\| <= 1e\+09\)"):
        CalibrateConfig(registration={"max_range_m": 1e10})


@pytest.mark.parametrize("text, caps", [
    ("{}", (5, 2, 2)),
    ("odometry:\n  fusion:\n    degeneracy_every: 4\n", (5, 2, 2)),  # was (None, None): the section replaced the default
    ("odometry:\n  registration:\n    max_range_m: 80\n", (5, 2, 2)),
    ("odometry:\n  registration:\n    steady_iterations: null\n    slow_iterations: null\n", (None, None, 2)),
    ("odometry:\n  registration:\n    slow_register_every: 1\n", (5, 2, 1)),
])
def test_deskew_keeps_its_icp_caps_unless_told(tmp_path, text, caps):
    from lio_cli.config.deskew import DeskewConfig

    path = tmp_path / "deskew.yaml"
    path.write_text(text)
    cfg = load_model(DeskewConfig, path)
    rc = cfg.odom_config("imu").registration
    assert (rc.steady_iterations, rc.slow_iterations, rc.slow_register_every) == caps
    assert OdomConfig().registration.slow_register_every == 1
    assert (rc.slow_rate_degps, OdomConfig().registration.slow_rate_degps) == (10.0, 5.0)
    assert (OdomConfig().registration.steady_iterations, OdomConfig().registration.slow_iterations) == (None, None)
    # and its sparser degeneracy analysis of clear scenes, also when the YAML names other fusion fields
    assert (cfg.odom_config("imu").fusion.degeneracy_every_clear, OdomConfig().fusion.degeneracy_every_clear) == (8, 4)
    assert load_model(DeskewConfig, _dumped(tmp_path, cfg)).odometry == cfg.odometry  # the written config repeats it


def _dumped(tmp_path, cfg):
    path = tmp_path / "again.yaml"
    path.write_text(dump_model(cfg))
    return path


@pytest.mark.parametrize("model, text, message", [
    ("odom", "registration:\n  max_points_per_voxel: 1000000000000000\n",
     "registration.max_points_per_voxel: must be within (0, 1000], got 1000000000000000"),
    ("odom", "registration:\n  threads: 1000000000000000\n", "registration.threads: must be within [0, 1024], got 1000000000000000"),
    ("deskew", "odometry:\n  registration:\n    slow_register_every: 1000000000000000\n",
     "odometry.registration.slow_register_every: must be within [1, 4], got 1000000000000000"),
    ("calibrate", "registration:\n  threads: 1000000000000000\n",
     "registration.threads: must be within [0, 1024], got 1000000000000000"),
    ("fuse", "gate_max_rejects: 0\n", "gate_max_rejects: must be within [1, 1e+06], got 0"),
])
def test_integer_fields_out_of_range_are_one_line_naming_field_and_range(tmp_path, model, text, message):
    from lio_cli.config.calibrate import CalibrateConfig
    from lio_cli.config.deskew import DeskewConfig
    from lio_cli.config.fuse import FuseConfig

    path = tmp_path / "c.yaml"
    path.write_text(text)
    cls = {"odom": OdomConfig, "deskew": DeskewConfig, "calibrate": CalibrateConfig, "fuse": FuseConfig}[model]
    with pytest.raises(ConfigError) as err:
        load_model(cls, path)
    assert str(err.value) == f"{path}: {message}"


def test_every_integer_field_of_every_config_model_has_an_upper_bound():
    """A count of 10^15 overflows kiss-icp's C++ ints or allocates for ever: every int field is bounded."""
    import typing

    from pydantic import BaseModel

    import lio_cli.batch.manifest as manifest
    from lio_cli.config import Strict
    from lio_cli.config.calibrate import CalibrateConfig
    from lio_cli.config.deskew import DeskewConfig
    from lio_cli.config.fuse import FuseConfig
    from lio_cli.model.calibration import Calibration

    seen, unbounded = set(), []

    def walk(model):
        if model in seen:
            return
        seen.add(model)
        for name, info in model.model_fields.items():
            args = typing.get_args(info.annotation) or (info.annotation,)
            if int in args and not any(getattr(m, a, None) is not None for m in info.metadata for a in ("le", "lt")):
                unbounded.append(f"{model.__name__}.{name}")
            for a in args:
                if isinstance(a, type) and issubclass(a, BaseModel):
                    walk(a)

    for m in (OdomConfig, DeskewConfig, CalibrateConfig, FuseConfig, Calibration, manifest.Manifest):
        walk(m)
    assert len(seen) > 15 and any(issubclass(m, Strict) for m in seen)
    assert unbounded == []
