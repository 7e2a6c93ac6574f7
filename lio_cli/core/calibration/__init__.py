"""Calibration estimators of ``lio calibrate``: pure functions of numpy arrays (no log reading, no files).

Inputs are what a log gives: a LiDAR odometry trajectory (``stamps_ns`` int64, ``T_world_lidar`` (N,4,4), world
= whatever frame the odometry uses, not necessarily levelled), raw IMU samples (``stamps_ns`` int64,
``gyro_radps``/``accel_mps2`` (M,3) in the IMU frame) and wheel odometry (stamps, forward speed, yaw rate).
Each estimator returns a frozen result with values, 1-sigmas and ``notes`` (what was skipped or assumed and
why), and raises ``InputError`` with one line when the data cannot give the answer (no still stretch, too
little motion, clocks that do not overlap).

A natural order: ``estimate_imu_static`` (gyro bias) -> ``estimate_time_offset`` -> ``estimate_rotation``
(with the offset and bias) -> ``estimate_lever_arm`` (with the rotation and its covariance, which it refines)
-> ``estimate_wheel_scales`` (with T_base_lidar). ``imu_time_offset_s`` is ADDED to IMU stamps to put them
on the LiDAR clock; rotations and lever arms are ``T_lidar_imu`` (IMU into LiDAR), so
``T_base_imu = T_base_lidar @ T_lidar_imu``.
"""

from ...lazy import lazy_exports

# Names load their module on first use (PEP 562): lio odom's online clock-offset estimator needs time_offset
# only, not the Allan fit (scipy.optimize's nnls), the lever arm and wheel estimators (scipy.linalg) or their
# plots, which would cost every odom and deskew run their import time.
_WHERE = {
    "AllanFit": "allan", "AllanResult": "allan", "allan_deviation": "allan", "estimate_allan": "allan",
    "ImuStatic": "imu_static", "StillOptions": "imu_static", "estimate_imu_static": "imu_static",
    "find_still_stretch": "imu_static",
    "LeverArmCalib": "lever_arm", "estimate_lever_arm": "lever_arm",
    "RotationCalib": "rotation", "estimate_rotation": "rotation",
    "TimeOffset": "time_offset", "estimate_time_offset": "time_offset",
    "WheelCalib": "wheel", "estimate_wheel_scales": "wheel",
}


__getattr__ = lazy_exports(__name__, _WHERE)


__all__ = [
    "AllanFit", "AllanResult", "ImuStatic", "LeverArmCalib", "RotationCalib", "StillOptions", "TimeOffset",
    "WheelCalib", "allan_deviation", "estimate_allan", "estimate_imu_static",
    "estimate_lever_arm", "estimate_rotation", "estimate_time_offset", "estimate_wheel_scales",
    "find_still_stretch",
]
