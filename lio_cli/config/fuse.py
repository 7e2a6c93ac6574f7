"""``lio fuse``'s configuration: which sources, which of their measurements, the noise, the estimator, the output.

The ``.config.yaml`` a run writes is this model after resolution (topics chosen, base frame found, wheel twist
frame decided, the measurement selection made explicit), so ``lio fuse LOG --config that.config.yaml`` repeats
the run exactly. The defaults are the estimation core's (``core.fuse.NoiseOptions``/``FuseOptions``; config sits
below core, so they are repeated here and a test holds them equal), except the odometry pose sigmas (see
``FuseNoise``); ``jobs.fuse`` turns this into the core's options.
"""

from __future__ import annotations

from typing import Literal, Optional

import numpy as np
from pydantic import Field, field_validator, model_validator

from ..errors import ConfigError
from ..model.calibration import MAX_CLOCK_OFFSET_S, Calibration
from . import MAX_COUNT, Strict

# measurement names per source, as the core names them (core.fuse.MEASUREMENTS)
MEASUREMENTS: dict[str, tuple[str, ...]] = {
    "imu": ("gyro", "accel", "orientation"),
    "wheel": ("speed", "velocity", "yaw_rate"),
    "odom": ("pose", "delta"),
    "gps": ("position",),
}
SOURCES = tuple(MEASUREMENTS)
# what a bare ``--use SOURCE`` selects
DEFAULT_USE = {"imu": ("gyro", "accel", "orientation"), "wheel": ("speed",), "odom": ("pose",), "gps": ("position",)}
DEFAULT_MAX_MEMORY_MB = 1024.0


class FuseInputConfig(Strict):
    """Where each source comes from (None: detected; the resolved config names what was used)."""

    format: Optional[Literal["ros1", "ros2", "mcap"]] = Field(None, description="log format; default: detected")
    imu_topic: Optional[str] = Field(None, description="sensor_msgs/Imu topic; default: the only one")
    wheel_topic: Optional[str] = Field(None, description="wheel odometry (Odometry or TwistStamped); default: the only one")
    gps_topic: Optional[str] = Field(None, description="sensor_msgs/NavSatFix topic; default: the only one")
    odom_topic: Optional[str] = Field(None, description="pose source of the log (Odometry, PoseStamped, TransformStamped); never guessed")
    odom_file: Optional[str] = Field(None, description="pose source file: TUM or KITTI (e.g. from lio odom), or LOG:/topic")
    base_frame: Optional[str] = Field(None, description="base frame in /tf_static; default base_link, base or base_footprint")
    wheel_twist_frame: Literal["auto", "child", "parent"] = Field(
        "auto", description="frame of the wheel twist: child (REP 105, the base), parent (some drivers), or auto: "
                            "decided from the message poses")
    gps_origin: Optional[list[float]] = Field(None, description="ENU origin latitude, longitude (deg), altitude (m); "
                                                                "default: the first valid fix")
    gps_antenna: Optional[list[float]] = Field(None, description="the GPS antenna in the base frame, x, y, z (m); "
                                                                 "default: /tf_static's base -> the fixes' frame")

    @model_validator(mode="after")
    def _one_odom(self) -> "FuseInputConfig":
        if self.odom_topic is not None and self.odom_file is not None:
            raise ValueError("give the odometry as odom_topic or odom_file, not both")
        if self.gps_origin is not None and (len(self.gps_origin) != 3 or not np.isfinite(self.gps_origin).all()):
            raise ValueError("gps_origin must be 3 finite numbers: latitude, longitude, altitude")
        if self.gps_antenna is not None and (len(self.gps_antenna) != 3 or not np.isfinite(self.gps_antenna).all()):
            raise ValueError("gps_antenna must be 3 finite numbers: x, y, z in the base frame (m)")
        return self


class FuseNoise(Strict):
    """Noise model. IMU values are continuous-time densities (as ``lio calibrate`` writes them); sigmas are the
    defaults for messages without a usable covariance (0, -1 or NaN)."""

    gyro_noise_density: float = Field(1.0e-3, gt=0, description="rad/s/sqrt(Hz)")
    accel_noise_density: float = Field(5.0e-2, gt=0, description="m/s^2/sqrt(Hz)")
    gyro_bias_walk: float = Field(1.0e-4, gt=0, description="rad/s^2/sqrt(Hz)")
    accel_bias_walk: float = Field(1.0e-3, gt=0, description="m/s^3/sqrt(Hz)")
    cv_accel_density: float = Field(1.0, gt=0, description="motion model without an IMU, m/s^2/sqrt(Hz)")
    cv_angular_accel_density: float = Field(1.0, gt=0, description="rad/s^2/sqrt(Hz)")
    wheel_speed_sigma_mps: float = Field(0.05, gt=0, description="wheel speed noise, m/s")
    wheel_speed_rel_sigma: float = Field(
        0.02, ge=0, description="plus this share of the speed, for each velocity component (a radius off by 1 % is "
        "0.1 m/s at 10 m/s): sigma = hypot(wheel_speed_sigma_mps, share x speed)")
    wheel_yaw_rate_sigma_radps: float = Field(0.05, gt=0, description="wheel yaw rate noise, rad/s")
    nonholonomic_sigma_mps: float = Field(0.05, gt=0, description="lateral/vertical body speed of a wheeled base")
    nonholonomic_rel_sigma: float = Field(
        0.03, ge=0, description="plus this share of the forward speed: a car's body pitches and slides (1 deg at "
        "10 m/s is 0.17 m/s of vertical body speed)")
    # above the core's 0.02 m / 0.005 rad: LiDAR odometry's pose errors drift (correlated), they are not white
    odom_position_sigma_m: float = Field(0.1, gt=0, description="per odometry pose without a covariance")
    odom_rotation_sigma_rad: float = Field(0.02, gt=0, description="per odometry pose without a covariance")
    gps_position_sigma_m: float = Field(2.0, gt=0, description="GPS horizontal noise without a usable covariance, m")
    gps_vertical_sigma_m: float = Field(5.0, gt=0, description="GPS altitude noise without a usable covariance, m")
    orientation_sigma_rad: float = Field(0.02, gt=0, description="IMU's own orientation")
    use_message_covariance: bool = Field(True, description="false: the sigmas above for every message")
    init_velocity_sigma_mps: float = Field(1.0, gt=0, description="initial velocity uncertainty")
    init_tilt_sigma_rad: float = Field(0.05, gt=0, description="initial roll and pitch uncertainty")
    init_gyro_bias_sigma_radps: float = Field(0.01, gt=0, description="initial gyro bias uncertainty")
    init_accel_bias_sigma_mps2: float = Field(0.2, gt=0, description="initial accelerometer bias uncertainty")


class FuseConfig(Strict):
    """Everything ``lio fuse`` can be told; flags override the YAML field by field."""

    unbounded_fields = frozenset({"time_offsets_s"})  # bounded by MAX_CLOCK_OFFSET_S below

    input: FuseInputConfig = FuseInputConfig()
    calibration: Calibration = Field(Calibration(), description="extrinsics where /tf_static is silent, IMU clock offset")
    time_offsets_s: dict[Literal["wheel", "gps", "odom"], float] = Field(
        {}, description="seconds added to each source's stamps to put it on the common clock, as "
                        "calibration.imu_time_offset_s is added to the IMU's (--time-offset SOURCE=SECONDS)")
    use: Optional[dict[Literal["imu", "wheel", "odom", "gps"], list[str]]] = Field(
        None, description="source -> measurements (imu: gyro, accel, orientation; wheel: speed, velocity, yaw_rate; "
                          "odom: pose or delta; gps: position); default: every source found, the core's selection")
    weigh_wheel_yaw: Optional[bool] = Field(
        None, description="beside a gyro, the wheels' yaw rate weighed against it over the log and used with the noise "
                          "it shows where it agrees; default: when use is not given")
    check_orientation: Optional[bool] = Field(
        None, description="the IMU's own orientation checked (its yaw variance, and whether it follows the gyro) and "
                          "left out where it fails; default: when use is not given")
    estimator: Literal["auto", "ekf", "planar", "complementary"] = Field(
        "auto", description="auto (planar for a wheeled robot whose motion stays near a plane, else ekf), ekf (3D "
                            "error-state), planar (SE(2): x, y, theta, v, omega, gyro bias) or complementary")
    smooth: bool = Field(True, description="smooth over the whole log (every measurement before and after each instant): "
                                           "the factor graph with an accelerometer, else the RTS pass; false: the filter alone")
    rate_hz: Optional[float] = Field(None, description="output rate; default: every IMU sample (exact stamps)")
    noise: FuseNoise = FuseNoise()
    gate_probability: float = Field(1e-4, ge=0, lt=1, description="chi-square gate; 0: none")
    gate_max_rejects: int = Field(5, ge=1, le=MAX_COUNT, description="after this many rejections in a row of one measurement "
                                  "kind the next is accepted, the states it touches made more uncertain")
    gap_periods: float = Field(5.0, gt=1, description="a pause of this many median periods is a gap")
    min_gap_s: float = Field(0.02, gt=0, description="a gap is at least this long")
    snap_s: float = Field(0.001, ge=0, description="wheel messages this close to an IMU sample are applied there")
    standing_window_s: float = Field(1.0, gt=0, description="the start window gravity and the first velocity are "
                                     "found over (twice this at a moving start)")
    gravity_mps2: float = Field(9.81, gt=0, le=30, description="magnitude of gravity, m/s^2")
    alpha_odom: float = Field(0.98, ge=0, le=1, description="complementary filter: weight of the odometry pose")
    alpha_orientation: float = Field(0.02, ge=0, le=1, description="complementary filter: weight of the IMU's own "
                                     "orientation")
    alpha_gps: float = Field(0.05, ge=0, le=1, description="complementary filter: weight of the GPS position")
    max_memory_mb: float = Field(DEFAULT_MAX_MEMORY_MB, gt=0, description=(
        "estimation memory budget: a run that would need more is fused in overlapping time chunks"))

    @field_validator("rate_hz")
    @classmethod
    def _rate(cls, v: float | None) -> float | None:
        if v is not None and not (np.isfinite(v) and v > 0):
            raise ValueError(f"must be a positive number of Hz, got {v}")
        return v

    @field_validator("time_offsets_s")
    @classmethod
    def _offsets(cls, v: dict) -> dict:
        for src, sec in v.items():
            if not (np.isfinite(sec) and abs(sec) <= MAX_CLOCK_OFFSET_S):
                raise ValueError(f"{src}: must be a finite number of seconds within +-{MAX_CLOCK_OFFSET_S:g}, got {sec}")
        return v

    @field_validator("use")
    @classmethod
    def _use(cls, v: dict | None) -> dict | None:
        if v is None:
            return v
        for src, names in v.items():
            bad = sorted(set(names) - set(MEASUREMENTS[src]))
            if bad:
                raise ValueError(f"unknown {src} measurement '{bad[0]}' (choose from {', '.join(MEASUREMENTS[src])})")
        return {s: sorted(set(m)) for s, m in v.items()}


def bare_sources(items: list[str] | None) -> set[str]:
    """The sources ``--use`` names without measurements (``wheel``, not ``wheel:speed``)."""
    return {src.strip() for src, _, names in (u.partition(":") for u in items or ()) if not names.strip()}


def parse_time_offsets(items: list[str]) -> dict[str, float]:
    """``--time-offset`` values (``gps=-0.3``, ``wheel=0.05``, ``imu=0.01``) as source -> seconds; one value per
    source."""
    out: dict[str, float] = {}
    for item in items:
        src, eq, value = (p.strip() for p in item.partition("="))
        if not eq or not src or not value:
            raise ConfigError(f"--time-offset {item}: expected SOURCE=SECONDS, e.g. gps=-0.3")
        if src not in SOURCES:
            raise ConfigError(f"--time-offset {item}: unknown source '{src}' (choose from {', '.join(SOURCES)})")
        try:
            sec = float(value)
        except ValueError:
            raise ConfigError(f"--time-offset {item}: '{value}' is not a number of seconds") from None
        if not (np.isfinite(sec) and abs(sec) <= MAX_CLOCK_OFFSET_S):
            raise ConfigError(f"--time-offset {item}: must be a finite number of seconds within "
                              f"+-{MAX_CLOCK_OFFSET_S:g}")
        if src in out and out[src] != sec:
            raise ConfigError(f"--time-offset {src} given twice ({out[src]:g} and {sec:g})")
        out[src] = sec
    return out


def parse_use(items: list[str]) -> dict[str, list[str]]:
    """``--use`` values (``imu:gyro,accel``, ``wheel``, ``gps:position``) as a selection; a bare source name
    selects its ``DEFAULT_USE`` measurements, and a bare ``wheel`` without the gyro its yaw rate too."""
    out: dict[str, list[str]] = {}
    bare = bare_sources(items)
    for item in items:
        src, _, names = item.partition(":")
        src = src.strip()
        if src not in MEASUREMENTS:
            raise ConfigError(f"--use {item}: unknown source '{src}' (choose from {', '.join(SOURCES)})")
        chosen = [n.strip() for n in names.split(",") if n.strip()] if names else list(DEFAULT_USE[src])
        out.setdefault(src, [])
        out[src] = sorted(set(out[src]) | set(chosen))
    if "wheel" in bare and "gyro" not in out.get("imu", ()):  # else nothing turns: a straight line
        out["wheel"] = sorted(set(out["wheel"]) | {"yaw_rate"})
    return out


__all__ = ["DEFAULT_USE", "MEASUREMENTS", "FuseConfig", "FuseInputConfig", "FuseNoise", "SOURCES", "bare_sources",
           "parse_time_offsets", "parse_use"]
