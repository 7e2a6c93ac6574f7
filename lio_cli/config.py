"""Typed configuration with sane defaults, loaded from YAML and overridden by CLI flags."""

from __future__ import annotations

from pathlib import Path
from typing import Literal, Optional

import yaml
from pydantic import BaseModel, ConfigDict, Field, ValidationError

from .errors import ConfigError


class _Strict(BaseModel):
    model_config = ConfigDict(extra="forbid")


class ImuNoise(_Strict):
    """Continuous-time IMU noise densities and random walks (typical MEMS values)."""

    gyro_noise_radps: float = Field(2e-3, gt=0, description="gyro white noise, rad/s/sqrt(Hz)")
    accel_noise_mps2: float = Field(2e-2, gt=0, description="accel white noise, m/s^2/sqrt(Hz)")
    gyro_bias_walk: float = Field(5e-5, gt=0, description="gyro bias random walk, rad/s^2/sqrt(Hz)")
    accel_bias_walk: float = Field(1e-3, gt=0, description="accel bias random walk, m/s^3/sqrt(Hz)")


class RegistrationConfig(_Strict):
    """kiss-icp registration and voxel map."""

    voxel_size_m: Optional[float] = Field(None, gt=0, description="map voxel size; default from the first scans' ranges")
    max_range_m: float = Field(100.0, gt=0)
    min_range_m: float = Field(0.5, ge=0)
    source_voxel_factor: Optional[float] = Field(
        None, gt=0, description="registration keeps one point per voxel_size x this; default 2.5 in 3D, 1.5 (kiss-icp's) for 2D scans")
    max_points_per_voxel: int = Field(5, gt=0, description="kiss-icp uses 20; 5 is faster and as accurate with an IMU prior")
    max_iterations: Optional[int] = Field(
        None, gt=0, description="ICP iterations per scan; default 20 with an IMU prior (it converges in a few), else 500")
    convergence: float = Field(1e-4, gt=0)
    initial_threshold_m: float = Field(2.0, gt=0, description="adaptive threshold's start (no IMU prior)")
    max_correspondence_m: Optional[float] = Field(
        None, gt=0, description="fixed correspondence distance; default: 0.5 m with an IMU prior, adaptive without")
    min_motion_m: float = Field(0.1, ge=0)
    threads: int = Field(0, ge=0, description="0: all cores")
    min_points: int = Field(50, gt=0, description="scans with fewer valid points are skipped")


class FusionConfig(_Strict):
    """How the registration result corrects the IMU state."""

    method: Literal["ekf", "complementary"] = "ekf"
    alpha: float = Field(0.98, ge=0, le=1, description="complementary filter: weight of the scan match")
    position_sigma_m: float = Field(0.03, gt=0, description="registration position noise per scan")
    rotation_sigma_rad: float = Field(0.005, gt=0, description="registration rotation noise per scan")
    degenerate_sigma_m: float = Field(2.0, gt=0, description="position noise along a degenerate direction")
    degeneracy_ratio: float = Field(0.025, gt=0, description="horizontal eigenvalue ratio below which a direction is degenerate")
    degeneracy_every: int = Field(2, ge=1, description="analyse the geometry every n-th scan, reuse it between")
    wheel_beta: float = Field(0.5, ge=0, le=1, description="complementary filter: weight of the wheel speed")
    wheel_speed_sigma_mps: float = Field(0.2, gt=0, description="wheel speed noise (covers slip episodes)")
    imu: ImuNoise = ImuNoise()


class OdomConfig(_Strict):
    """Everything ``lio odom`` can be told; CLI flags override the YAML."""

    deskew: Literal["imu", "constant-velocity", "none"] = "imu"
    prior: Literal["imu", "constant-velocity", "wheel", "none"] = "imu"
    use_wheel: bool = Field(True, description="join wheel odometry to the prediction when a wheel topic exists")
    scan_reference: Literal["end", "start"] = "end"
    frame: Literal["base", "lidar", "imu"] = "base"
    planar: Optional[bool] = Field(None, description="force SE(2) mode; default: on for LaserScan input")
    static_init_s: float = Field(1.0, gt=0, description="window examined for a standing start")
    gravity_mps2: float = 9.81
    registration: RegistrationConfig = RegistrationConfig()
    fusion: FusionConfig = FusionConfig()


def _read_mapping(path: Path, what: str) -> dict:
    """A YAML file's top-level mapping; every failure is a ConfigError naming the file."""
    try:
        data = yaml.safe_load(Path(path).read_text()) or {}
    except FileNotFoundError as err:
        raise ConfigError(f"{path}: no such {what} file") from err
    except (OSError, yaml.YAMLError) as err:
        raise ConfigError(f"{path}: cannot read {what} ({str(err).splitlines()[0]})") from err
    if not isinstance(data, dict):
        raise ConfigError(f"{path}: {what} must be a mapping of option: value")
    return data


def _validate(model: type[BaseModel], data: dict, where: str):
    try:
        return model.model_validate(data)
    except ValidationError as err:
        first = err.errors()[0]
        loc = ".".join(str(x) for x in first["loc"])
        raise ConfigError(f"{where}: {loc}: {first['msg']}") from err


def load_config(path: Path | None) -> OdomConfig:
    """Defaults, updated from a YAML file when given."""
    if path is None:
        return OdomConfig()
    return validate_config(_read_mapping(path, "config"), str(path))


def validate_config(data: dict, where: str) -> OdomConfig:
    return _validate(OdomConfig, data, where)


def dump_config(cfg: OdomConfig) -> str:
    return yaml.safe_dump(cfg.model_dump(mode="json"), sort_keys=False)


class Calibration(_Strict):
    """What ``--calib FILE`` may hold (all optional): extrinsics as 4x4 row lists, IMU clock offset, biases."""

    T_base_imu: Optional[list[list[float]]] = None
    T_base_lidar: Optional[list[list[float]]] = None
    imu_time_offset_s: float = Field(0.0, description="t_lidar_clock = t_imu_stamp + offset")
    gyro_bias_radps: Optional[list[float]] = None
    accel_bias_mps2: Optional[list[float]] = None


def load_calibration(path: Path) -> Calibration:
    cal = _validate(Calibration, _read_mapping(path, "calibration"), str(path))
    for name in ("T_base_imu", "T_base_lidar"):
        T = getattr(cal, name)
        if T is not None and (len(T) != 4 or any(len(row) != 4 for row in T)):
            raise ConfigError(f"{path}: {name} must be a 4x4 matrix (4 rows of 4 numbers)")
    return cal
