"""Synthetic inputs of the calibration estimators, with their truth, without writing a log.

What ``lio calibrate`` gets from a log is a LiDAR odometry trajectory (LiDAR-only registration: poses of the
LiDAR in the frame of its first scan, with a centimetre and a tenth of a degree of noise per pose), raw IMU
arrays and wheel odometry arrays. :func:`calibration_inputs` makes those from a scenario's exact motion and
sensor models, so tests and benchmarks know the truth. Conventions: ``imu_time_offset_s`` is ADDED to IMU
stamps to put them on the LiDAR's clock, as everywhere in lio.
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np

from ..geometry import inv_pose, so3_exp
from .scenarios import Scenario, build_scenario
from .sensors import NS, ImuData, ImuSpec, WheelOdometry, WheelSpec, synthesize_imu, wheel_odometry

START_NS = 1_700_000_000 * NS


@dataclass
class CalibrationInputs:
    scenario: Scenario
    lidar_stamps_ns: np.ndarray  # (N,) LiDAR clock = true time
    T_world_lidar: np.ndarray  # (N,4,4) noisy, world = the first LiDAR pose
    T_world_lidar_true: np.ndarray  # (N,4,4) noiseless, same world
    imu: ImuData  # stamps on the IMU clock, gyro/accel in the IMU frame
    imu_spec: ImuSpec
    imu_time_offset_s: float  # truth: t_lidar = t_imu_stamp + offset
    T_lidar_imu: np.ndarray  # truth
    wheel: WheelOdometry | None
    wheel_spec: WheelSpec | None

    @property
    def T_base_imu(self) -> np.ndarray:
        return self.scenario.T_base_imu

    @property
    def T_base_lidar(self) -> np.ndarray:
        return self.scenario.T_base_lidar


def calibration_inputs(scenario: str | Scenario = "handheld", duration_s: float = 40.0, seed: int = 0, *,
                       imu_time_offset_s: float = 0.0, pos_noise_m: float = 0.015, rot_noise_deg: float = 0.1,
                       lidar_rate_hz: float = 10.0, imu_spec: ImuSpec | None = None,
                       T_base_imu: np.ndarray | None = None, wheel_spec: WheelSpec | None = None) -> CalibrationInputs:
    """LiDAR trajectory, IMU and (when the scenario has wheels) wheel odometry over ``duration_s``.

    ``imu_spec`` None: the simulator's default noise with biases drawn from ``seed``; ``T_base_imu`` overrides
    the scenario's IMU mounting; ``wheel_spec`` the scenario's wheels (scale errors, slip)."""
    sc = build_scenario(scenario) if isinstance(scenario, str) else scenario
    if T_base_imu is not None:
        sc = replace(sc, T_base_imu=np.asarray(T_base_imu, np.float64))
    rng = np.random.default_rng(seed)
    if imu_spec is None:
        imu_spec = ImuSpec(accel_bias0_mps2=rng.normal(0.0, 0.04, 3), gyro_bias0_radps=rng.normal(0.0, 0.003, 3))
    imu_spec = replace(imu_spec, imu_time_offset_ns=int(round(imu_time_offset_s * NS)))
    end_ns = START_NS + int(round(duration_s * NS))
    lidar_ns = np.arange(START_NS, end_ns + 1, int(round(NS / lidar_rate_hz)), dtype=np.int64)
    T_wl = sc.trajectory.poses((lidar_ns - START_NS) * 1e-9) @ sc.T_base_lidar
    T_wl = inv_pose(T_wl[0]) @ T_wl
    noisy = T_wl.copy()
    noisy[:, :3, 3] += rng.normal(0.0, pos_noise_m, (len(lidar_ns), 3))
    noisy[:, :3, :3] = noisy[:, :3, :3] @ so3_exp(rng.normal(0.0, np.radians(rot_noise_deg), (len(lidar_ns), 3)))
    imu = synthesize_imu(sc.trajectory, sc.T_base_imu, imu_spec, START_NS, end_ns, START_NS, rng)
    wspec = wheel_spec if wheel_spec is not None else sc.wheels
    wheel = wheel_odometry(sc.trajectory, wspec, START_NS, end_ns, START_NS) if wspec is not None else None
    return CalibrationInputs(sc, lidar_ns, noisy, T_wl, imu, imu_spec, float(imu_time_offset_s),
                             inv_pose(sc.T_base_lidar) @ sc.T_base_imu, wheel, wspec)
