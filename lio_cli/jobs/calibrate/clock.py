"""The IMU's clock offset from the wheels (a ground vehicle's), beside the one from the LiDAR's rotations.

A robot with a 2D scanner times its IMU against the LiDAR to a millisecond or two at best (its scans' rotations
are noisy); its wheels' yaw rate shows the same turns without registration (``core.calibration.
clock_from_wheels``). Measured once from the whole log, before the passes; ``estimate.extrinsics`` combines it
with each round's LiDAR estimate (``with_wheel_clock``).
"""

from __future__ import annotations

from ...config.calibrate import CalibrateConfig
from ...core.calibration.clock_from_wheels import estimate_clock_from_wheels
from ...errors import InputError
from ...model.records import ImuBatch
from .estimate import FINAL_MAX_SIGMA_S, Estimates
from .passes import SensorArrays


def wheel_clock(arrays: SensorArrays, imu: ImuBatch, cfg: CalibrateConfig, est: Estimates) -> None:
    """``est.wheel_clock`` from the wheels' yaw rate against the gyro, when the log has wheels and their turns
    time the IMU (else a note saying why not)."""
    if not arrays.has_wheels:
        return
    try:
        est.wheel_clock = estimate_clock_from_wheels(
            arrays.wheel_stamps_ns, arrays.wheel_angular_radps, imu.stamps_ns, imu.gyro_radps,
            speed_mps=arrays.wheel_linear_mps,
            centre_s=cfg.start_offset_s, max_offset_s=cfg.max_offset_s, max_sigma_s=FINAL_MAX_SIGMA_S)
    except InputError as err:
        est.notes.append(str(err))
        return
    est.notes.extend(est.wheel_clock.notes)
