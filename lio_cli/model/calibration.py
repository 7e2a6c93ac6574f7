"""Sensor calibration: extrinsics, IMU clock offset and biases, as read from ``--calib`` or a config."""

from __future__ import annotations

from dataclasses import dataclass, replace
from typing import Optional

import numpy as np
from pydantic import BaseModel, ConfigDict, Field, ValidationInfo, field_validator

from .records import OdometryRecord

# |imu_time_offset_s| beyond this would overflow int64 ns stamps (clock offsets of epoch-sized clocks still fit).
MAX_CLOCK_OFFSET_S = 4e9
# Physical bounds of a calibration's values (docs/commands/calibrate.md lists them): far beyond any real sensor,
# far below what would overflow the filters. A value outside is a typo or a corrupt file, refused by name.
MAX_CLOCK_SIGMA_S = 10.0  # 1-sigma of the clock offset; calibrate searches at most +-5 s
MAX_LEVER_ARM_M = 100.0  # |translation| of an extrinsic: a sensor within 100 m of the base
MAX_GYRO_BIAS_RADPS = 1.0  # 57 deg/s; a MEMS gyro's bias is a few deg/s at worst
MAX_ACCEL_BIAS_MPS2 = 5.0  # half a g; a MEMS accelerometer's bias is a few tenths of m/s^2
MAX_ROTATION_SIGMA_RAD = 2 * np.pi  # a wider 1-sigma says nothing more
MAX_GYRO_NOISE = 1.0  # rad/s/sqrt(Hz) white noise and rad/s^2/sqrt(Hz) walk; MEMS gyros: about 1e-3
MAX_ACCEL_NOISE = 10.0  # m/s^2/sqrt(Hz) white noise and m/s^3/sqrt(Hz) walk; MEMS accelerometers: about 1e-2
MAX_WHEEL_SCALE = 10.0  # true over measured speed or yaw rate
MAX_WHEEL_SIZE_M = 100.0  # wheel radius, baseline and their sigmas
_ORTHO_TOL = 1e-3
# a mounting rotation whose 1-sigma exceeds this was not measured about that axis (the motion hardly showed it)
ARBITRARY_SIGMA_RAD = float(np.radians(2.5))


def _vector3(v: list[float] | None) -> list[float] | None:
    if v is not None and (len(v) != 3 or not np.isfinite(v).all()):
        raise ValueError("must be 3 finite numbers (x, y, z)")
    return v


def _within(v: list[float] | None, low: float, high: float, unit: str) -> list[float] | None:
    """``v`` when each of its numbers lies in [low, high], else a ValueError giving the range."""
    if v is not None and not all(low <= x <= high for x in v):
        bad = next(x for x in v if not low <= x <= high)
        raise ValueError(f"each value must be within [{low:.4g}, {high:.4g}] {unit}, got {bad:g}")
    return v


class ImuNoiseCalibration(BaseModel):
    """IMU noise as ``lio calibrate`` measured it (continuous-time densities, mean of the three axes)."""

    model_config = ConfigDict(extra="forbid")

    source: str = Field("", description="still stretch or Allan variance, and over how long")
    gyro_noise_radps: Optional[float] = Field(None, ge=0, le=MAX_GYRO_NOISE, description="gyro white noise, rad/s/sqrt(Hz)")
    accel_noise_mps2: Optional[float] = Field(None, ge=0, le=MAX_ACCEL_NOISE, description="accel white noise, m/s^2/sqrt(Hz)")
    gyro_bias_walk: Optional[float] = Field(None, ge=0, le=MAX_GYRO_NOISE, description="gyro bias random walk, rad/s^2/sqrt(Hz)")
    accel_bias_walk: Optional[float] = Field(None, ge=0, le=MAX_ACCEL_NOISE, description="accel bias random walk, m/s^3/sqrt(Hz)")
    gyro_bias_instability_radps: Optional[float] = Field(None, ge=0, le=MAX_GYRO_BIAS_RADPS)
    accel_bias_instability_mps2: Optional[float] = Field(None, ge=0, le=MAX_ACCEL_BIAS_MPS2)


class WheelCalibration(BaseModel):
    """Wheel odometry scale factors: true speed = speed_scale * wheel speed, likewise the yaw rate."""

    model_config = ConfigDict(extra="forbid")

    topic: Optional[str] = Field(None, description="the wheel odometry topic the scales were measured on: odom and "
                                 "fuse correct that topic only (none given: whichever they use)")
    speed_scale: float = Field(gt=0, le=MAX_WHEEL_SCALE)
    speed_scale_sigma: float = Field(ge=0, le=MAX_WHEEL_SCALE)
    yaw_rate_scale: float = Field(gt=0, le=MAX_WHEEL_SCALE)
    yaw_rate_scale_sigma: float = Field(ge=0, le=MAX_WHEEL_SCALE)
    radius_m: Optional[float] = Field(None, gt=0, le=MAX_WHEEL_SIZE_M, description="mean wheel radius (with the nominal one given)")
    radius_sigma_m: Optional[float] = Field(None, ge=0, le=MAX_WHEEL_SIZE_M)
    baseline_m: Optional[float] = Field(None, gt=0, le=MAX_WHEEL_SIZE_M, description="effective track width (with the nominal one given)")
    baseline_sigma_m: Optional[float] = Field(None, ge=0, le=MAX_WHEEL_SIZE_M)

    def verdict(self, topic: str) -> tuple[bool, str]:
        """Whether the scales apply to the wheel odometry ``topic``, and the words that say so."""
        if self.topic is None or self.topic == topic:
            return True, f"scaled by --calib (speed x{self.speed_scale:.6g}, yaw rate x{self.yaw_rate_scale:.6g})"
        return False, f"the wheel scales of --calib were measured on {self.topic}, not {topic}: not applied"

    def corrected(self, rec: OdometryRecord) -> OdometryRecord:
        """A wheel odometry record with its forward speed and yaw rate corrected (the twist as a whole scales by
        ``speed_scale``, the rotation about z by ``yaw_rate_scale``)."""
        angular = rec.angular_radps.copy()
        angular[2] *= self.yaw_rate_scale
        return replace(rec, linear_mps=rec.linear_mps * self.speed_scale, angular_radps=angular)


class Calibration(BaseModel):
    """What a calibration may hold (all optional): extrinsics as 4x4 row lists, IMU clock offset, biases, and
    what ``lio calibrate`` writes beside them: wheel scales, which odom and fuse apply to the wheel twist, and
    1-sigmas and IMU noise, which the other commands read without using.

    ``T_base_imu``/``T_base_lidar`` map sensor points into the base frame; ``imu_time_offset_s`` is added to
    IMU stamps to put them on the LiDAR's clock.
    """

    model_config = ConfigDict(extra="forbid")

    T_base_imu: Optional[list[list[float]]] = Field(
        None, description="4x4 rows mapping IMU points into the base frame (metres); null: /tf_static, else identity")
    T_base_lidar: Optional[list[list[float]]] = Field(
        None, description="4x4 rows mapping LiDAR points into the base frame (metres); null: /tf_static, else identity")
    imu_time_offset_s: float = Field(0.0, description="seconds added to IMU stamps to put them on the LiDAR's clock: "
                                     "t_lidar_clock = t_imu_stamp + offset")
    gyro_bias_radps: Optional[list[float]] = Field(None, description="gyro bias x, y, z in the IMU frame, rad/s")
    accel_bias_mps2: Optional[list[float]] = Field(None, description="accelerometer bias x, y, z in the IMU frame, m/s^2")
    # 1-sigmas beside the values (rotation about and translation along the base axes)
    imu_time_offset_sigma_s: Optional[float] = Field(None, ge=0, le=MAX_CLOCK_SIGMA_S, description="1-sigma of imu_time_offset_s (read, not used)")
    T_base_imu_rotation_sigma_rad: Optional[list[float]] = Field(
        None, description="1-sigma of T_base_imu's rotation about the base x, y, z axes (a large one: not measured)")
    T_base_imu_translation_sigma_m: Optional[list[float]] = Field(
        None, description="1-sigma of T_base_imu's translation along the base x, y, z axes (read, not used)")
    gyro_bias_sigma_radps: Optional[list[float]] = Field(None, description="1-sigma of gyro_bias_radps (read, not used)")
    accel_bias_sigma_mps2: Optional[list[float]] = Field(None, description="1-sigma of accel_bias_mps2 (read, not used)")
    imu_noise: Optional[ImuNoiseCalibration] = Field(None, description="IMU noise lio calibrate measured (read, not used)")
    wheel: Optional[WheelCalibration] = Field(
        None, description="wheel odometry speed and yaw-rate scales lio calibrate measured; odom and fuse apply them")
    prefer_file: bool = Field(False, description="use these extrinsics even where /tf_static gives one (--prefer-calib)")

    @field_validator("T_base_imu", "T_base_lidar")
    @classmethod
    def _rigid(cls, T: list[list[float]] | None) -> list[list[float]] | None:
        if T is None:
            return T
        if len(T) != 4 or any(len(row) != 4 for row in T):
            raise ValueError("must be a 4x4 matrix (4 rows of 4 numbers)")
        M = np.asarray(T, dtype=np.float64)
        if not np.isfinite(M).all():
            raise ValueError("holds a non-finite number")
        R = M[:3, :3]
        if np.abs(M[:3, 3]).max() > MAX_LEVER_ARM_M:
            raise ValueError(f"translation must be within [-{MAX_LEVER_ARM_M:g}, {MAX_LEVER_ARM_M:g}] m on each axis, "
                             f"got {M[np.abs(M[:3, 3]).argmax(), 3]:g} m")
        if np.abs(R.T @ R - np.eye(3)).max() > _ORTHO_TOL or np.linalg.det(R) <= 0 or \
                np.abs(M[3] - [0, 0, 0, 1]).max() > _ORTHO_TOL:
            raise ValueError("is not a rigid transform (rotation block not orthonormal or last row not 0 0 0 1)")
        return T

    @field_validator("imu_time_offset_s")
    @classmethod
    def _offset(cls, v: float) -> float:
        if not np.isfinite(v) or abs(v) > MAX_CLOCK_OFFSET_S:
            raise ValueError(f"must be a finite number of seconds within +-{MAX_CLOCK_OFFSET_S:g}")
        return v

    @field_validator("gyro_bias_radps", "accel_bias_mps2", "gyro_bias_sigma_radps", "accel_bias_sigma_mps2")
    @classmethod
    def _bias(cls, v: list[float] | None, info: ValidationInfo) -> list[float] | None:
        if v is not None and (len(v) != 3 or not np.isfinite(v).all()):
            raise ValueError("must be 3 finite numbers (x, y, z in the IMU frame)")
        bound, unit = (MAX_GYRO_BIAS_RADPS, "rad/s") if "gyro" in info.field_name else (MAX_ACCEL_BIAS_MPS2, "m/s^2")
        return _within(v, 0.0 if "sigma" in info.field_name else -bound, bound, unit)

    @field_validator("T_base_imu_rotation_sigma_rad", "T_base_imu_translation_sigma_m")
    @classmethod
    def _sigma3(cls, v: list[float] | None, info: ValidationInfo) -> list[float] | None:
        bound, unit = (MAX_ROTATION_SIGMA_RAD, "rad") if "rotation" in info.field_name else (MAX_LEVER_ARM_M, "m")
        return _within(_vector3(v), 0.0, bound, unit)

    @property
    def imu_time_offset_ns(self) -> int:
        return int(round(self.imu_time_offset_s * 1e9))

    def unmeasured_rotation(self) -> str | None:
        """A warning when ``T_base_imu``'s rotation was not measured about some base axis (its 1-sigma beyond
        ``ARBITRARY_SIGMA_RAD``: ``lio calibrate`` could not see it, e.g. a ground robot's IMU yaw, and wrote a
        guess), else None."""
        s = self.T_base_imu_rotation_sigma_rad
        if self.T_base_imu is None or s is None:
            return None
        axes = [(a, v) for a, v in zip("xyz", s) if v > ARBITRARY_SIGMA_RAD]
        if not axes:
            return None
        said = ", ".join(f"{a} (1-sigma {np.degrees(v):.1f} deg)" for a, v in axes)
        return (f"T_base_imu of --calib was not measured about the base {said}: the IMU's mounting there is a "
                "guess; give the drawing's value (or /tf_static) if the trajectory turns out wrong")

    def matrix(self, name: str) -> np.ndarray | None:
        """``T_base_imu`` or ``T_base_lidar`` as a (4,4) array, None when not given."""
        T = getattr(self, name)
        return None if T is None else np.asarray(T, dtype=np.float64)


@dataclass
class Extrinsics:
    """Rigid mounting of IMU and LiDAR on the base."""

    T_base_imu: np.ndarray
    T_base_lidar: np.ndarray

    @property
    def R_base_imu(self) -> np.ndarray:
        return self.T_base_imu[:3, :3]

    @property
    def lever_m(self) -> np.ndarray:
        return self.T_base_imu[:3, 3]
