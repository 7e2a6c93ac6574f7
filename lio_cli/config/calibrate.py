"""``lio calibrate``'s configuration: everything a run needs besides the log and its outputs.

The ``.config.yaml`` a run writes is this model after resolution (topics chosen, base frame found), so
``lio calibrate LOG --config that.config.yaml`` repeats the run. ``prior`` is what the estimates are compared
with (``--calib``); /tf_static, when the log has it, is compared too.

The IMU clock offset has one sign convention everywhere: added to IMU stamps to put them on the LiDAR's clock.
odom, deskew and fuse apply theirs (``calibration.imu_time_offset_s``, which ``--imu-time-offset`` sets);
calibrate measures it, so its ``--imu-time-offset`` sets ``imu_time_offset_s`` here: the value the measurement
starts from and keeps where the motion cannot time the IMU. ``prior`` is the reference the results are
compared with; of it only T_base_lidar and the clock offset are used, as defaults.
"""

from __future__ import annotations

import math
import re
from typing import Optional

from pydantic import Field, field_validator

from ..model.calibration import MAX_CLOCK_OFFSET_S, MAX_WHEEL_SIZE_M, Calibration
from . import MAX_THREADS, Strict
from .odom import InputConfig, RegistrationConfig

_STILL = re.compile(r"^\s*([0-9.eE+-]+)\s*:\s*([0-9.eE+-]+)\s*$")


def parse_still(text: str) -> tuple[float, float]:
    """``"START:END"`` (seconds after the log's first message) -> (start_s, end_s); ValueError when not so."""
    m = _STILL.match(text)
    try:
        a, b = (float(m.group(1)), float(m.group(2))) if m else (math.nan, math.nan)
    except ValueError:
        a, b = math.nan, math.nan
    if not (math.isfinite(a) and math.isfinite(b) and 0 <= a < b):
        raise ValueError(f"'{text}' is not START:END in seconds after the first IMU sample with 0 <= START < END "
                         "(e.g. 0:2.5)")
    return a, b


class CalibrationRegistration(RegistrationConfig):
    """odom's registration settings on one thread by default: kiss-icp's parallel sums change order from run to
    run, and a calibration's passes would carry that on."""

    threads: int = Field(1, ge=0, le=MAX_THREADS, description="1: the same log gives the same calibration; 0: all cores")


class CalibrateConfig(Strict):
    """Everything ``lio calibrate`` can be told; flags override the YAML field by field."""

    input: InputConfig = InputConfig()
    prior: Calibration = Field(Calibration(), description="a calibration to compare with (--calib); its "
                               "T_base_lidar is used where /tf_static is silent, its imu_time_offset_s is the "
                               "default of imu_time_offset_s")
    unbounded_fields = frozenset({"imu_time_offset_s"})
    imu_time_offset_s: Optional[float] = Field(
        None, ge=-MAX_CLOCK_OFFSET_S, le=MAX_CLOCK_OFFSET_S,  # as --calib's: an IMU on another clock (epoch) too
        description="seconds added to IMU stamps to put them on the LiDAR's clock (as odom's "
        "calibration.imu_time_offset_s): where the passes start and the search is centred, and kept where the "
        "motion cannot time the IMU (a vehicle that does not swing its sensor); default: prior's")
    still: Optional[str] = Field(None, description="START:END, seconds after the first IMU sample, where the IMU rests; "
                                 "default: found automatically")
    allan: bool = Field(False, description="Allan variance of the whole log (a static IMU recording, hours)")
    wheel_radius_m: Optional[float] = Field(None, gt=0, le=MAX_WHEEL_SIZE_M, description="nominal wheel radius: estimate the true one")
    wheel_baseline_m: Optional[float] = Field(None, gt=0, le=MAX_WHEEL_SIZE_M, description="nominal wheel baseline: estimate the true one")
    max_offset_s: float = Field(0.5, gt=0, le=5.0, description="largest IMU-LiDAR time offset searched (either sign)")
    refine_passes: int = Field(
        3, ge=0, le=4,
        description="gyro-primed odometry passes after the LiDAR-only one, each with the previous estimates and "
        "then the estimates again: the gyro's rotation (through the estimated mounting, clock offset and bias) "
        "primes each scan's registration and de-skews it, while the pose is the registration's own, never fused "
        "with the IMU (a fused pose would follow the estimates it starts from); all but the last over the first quarter of the "
        "log; 0 = the LiDAR-only pass alone (over the whole log; before refining passes it covers the first half, at "
        "least 20 s)")
    map_rounds: int = Field(
        3, ge=0, le=6,
        description="after the last pass, rounds that register each of its scans point-to-plane against one map of "
        "all of them (de-skewed with the gyro through the estimates so far), the estimates taken again after each; "
        "3D scans and logs up to 3000 scans only; 0 = the passes' poses")
    registration: CalibrationRegistration = CalibrationRegistration()

    @property
    def start_offset_s(self) -> float:
        """The IMU clock offset the passes start from and the search is centred on: the given one, else the
        prior's (0 without --calib)."""
        return self.prior.imu_time_offset_s if self.imu_time_offset_s is None else self.imu_time_offset_s

    @property
    def start_offset_ns(self) -> int:
        return int(round(self.start_offset_s * 1e9))

    @field_validator("still")
    @classmethod
    def _still(cls, v: str | None) -> str | None:
        if v is not None:
            parse_still(v)
        return v


__all__ = ["CalibrateConfig", "CalibrationRegistration", "parse_still"]
