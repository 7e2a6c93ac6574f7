"""Fusion test cases from the simulator: a scenario's exact trajectory, its noisy IMU and wheel odometry,
a LiDAR-odometry-like pose stream (true poses with white noise and slow drift) and GPS fixes.

No log is written: the arrays go straight into ``lio_cli.core.fuse`` inputs, so tests and benchmarks of the
estimators run in milliseconds to seconds.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..core.fuse.inputs import FuseInputs, GpsSeries, ImuSeries, PoseSeries, WheelSeries
from ..geometry import so3_exp
from .scenarios import build_scenario
from .sensors import NS, ImuSpec, WheelSpec, synthesize_imu, wheel_odometry

START_NS = 1_700_000_000 * NS  # an epoch-like start, so absolute-time precision is exercised


@dataclass
class OdomNoise:
    """Pose stream errors: white noise per pose, and a drift whose yaw and position are random walks."""

    rate_hz: float = 10.0
    position_sigma_m: float = 0.02
    rotation_sigma_rad: float = np.radians(0.2)
    drift_yaw_rw: float = 0.002  # rad/sqrt(s)
    drift_position_rw: float = 0.005  # m/sqrt(s)


@dataclass
class FusionCase:
    truth_stamps_ns: np.ndarray  # 100 Hz
    truth_poses: np.ndarray
    inputs: FuseInputs
    wheel_dead_reckoning: np.ndarray | None  # (M,4,4) at inputs.wheel stamps: the wheels integrated alone
    odom_truth_poses: np.ndarray | None  # true poses at the odometry stamps


def _wheel_spec(spec: WheelSpec, duration_s: float, errors: bool) -> WheelSpec:
    if errors:  # typical calibration errors of a diff-drive base and one slip episode
        spec.radius_scale_left, spec.radius_scale_right, spec.baseline_scale = 1.01, 0.99, 1.05
        spec.slip_start_s, spec.slip_duration_s = 0.4 * duration_s, 2.0
        spec.slip_left, spec.slip_right = 0.25, 0.10
    return spec


def simulate_case(scenario: str, duration_s: float, seed: int = 0, *, imu_rate_hz: float = 200.0,
                  imu_noise_scale: float = 1.0, wheels: bool = True, wheel_errors: bool = True,
                  odom: OdomNoise | None = None, gps_sigma_m: float | None = None,
                  gps_rate_hz: float = 5.0, imu_lever_arm_m: tuple[float, float, float] | None = None,
                  hills: tuple[float, float] | None = None) -> FusionCase:
    """A scenario's first ``duration_s`` as fusion inputs (IMU always; wheels, odometry, GPS on request).
    ``imu_lever_arm_m``: the IMU origin in base instead of the scenario's (its mounting rotation kept);
    ``hills``: (amplitude, wavelength) m of ground height along the path (``terrain``)."""
    rng = np.random.default_rng(seed)
    sc = build_scenario(scenario, hills=hills)
    if imu_lever_arm_m is not None:
        sc.T_base_imu = sc.T_base_imu.copy()
        sc.T_base_imu[:3, 3] = imu_lever_arm_m
    traj = sc.trajectory
    end_ns = START_NS + int(round(duration_s * NS))
    spec = ImuSpec(rate_hz=imu_rate_hz)
    spec.accel_noise_density *= imu_noise_scale
    spec.gyro_noise_density *= imu_noise_scale
    spec.accel_bias0_mps2 = np.clip(rng.normal(0.0, 0.04, 3), -0.1, 0.1) * imu_noise_scale
    spec.gyro_bias0_radps = np.clip(rng.normal(0.0, 0.003, 3), -0.01, 0.01) * imu_noise_scale
    imu = synthesize_imu(traj, sc.T_base_imu, spec, START_NS, end_ns, START_NS, rng)
    truth_ns = np.arange(START_NS, end_ns + 1, NS // 100, dtype=np.int64)
    truth = traj.poses((truth_ns - START_NS) * 1e-9)
    inputs = FuseInputs(imu=ImuSeries(imu.stamps_ns, imu.gyro_radps, imu.accel_mps2, sc.T_base_imu))
    dr = None
    if wheels and sc.wheels is not None:
        wo = wheel_odometry(traj, _wheel_spec(sc.wheels, duration_s, wheel_errors), START_NS, end_ns, START_NS)
        vel = np.column_stack([wo.linear_mps, np.full(len(wo.stamps_ns), np.nan), np.full(len(wo.stamps_ns), np.nan)])
        inputs.wheel = WheelSeries(wo.stamps_ns, vel, wo.angular_radps)
        dr = wo.poses_odom_base
    odom_truth = None
    if odom is not None:
        inputs.odom, odom_truth = _odom_stream(traj, end_ns, odom, rng)
    if gps_sigma_m is not None:
        g_ns = np.arange(START_NS, end_ns + 1, int(NS / gps_rate_hz), dtype=np.int64)
        p = traj.poses((g_ns - START_NS) * 1e-9)[:, :3, 3] + rng.normal(0.0, gps_sigma_m, (len(g_ns), 3))
        inputs.gps = GpsSeries(g_ns, p, np.broadcast_to(np.eye(3) * gps_sigma_m**2, (len(g_ns), 3, 3)).copy())
    return FusionCase(truth_ns, truth, inputs, dr, odom_truth)


def _odom_stream(traj, end_ns: int, n: OdomNoise, rng: np.random.Generator) -> tuple[PoseSeries, np.ndarray]:
    """Odometry as it drifts: each true increment between poses picks up a small yaw and translation
    error (so the heading error is a random walk and the position error its integral, locally consistent
    like real scan matching), then each pose gets white noise."""
    st = np.arange(START_NS, end_ns + 1, int(NS / n.rate_hz), dtype=np.int64)
    true = traj.poses((st - START_NS) * 1e-9)
    m, dt = len(st), 1.0 / n.rate_hz
    inc_err = np.zeros((m, 4, 4))
    inc_err[:, :3, :3] = so3_exp(np.column_stack([np.zeros((m, 2)), rng.normal(0.0, n.drift_yaw_rw * np.sqrt(dt), m)]))
    inc_err[:, :3, 3] = rng.normal(0.0, n.drift_position_rw * np.sqrt(dt), (m, 3))
    inc_err[:, 3, 3] = 1.0
    drifted = np.empty_like(true)
    drifted[0] = true[0]
    for k in range(1, m):
        drifted[k] = drifted[k - 1] @ np.linalg.inv(true[k - 1]) @ true[k] @ inc_err[k]
    white = np.zeros_like(true)
    white[:, :3, :3] = so3_exp(rng.normal(0.0, n.rotation_sigma_rad, (m, 3)))
    white[:, :3, 3] = rng.normal(0.0, n.position_sigma_m, (m, 3))
    white[:, 3, 3] = 1.0
    sig_p = np.full(m, n.position_sigma_m)
    sig_r = np.full(m, n.rotation_sigma_rad)
    return PoseSeries(st, drifted @ white, sig_p, sig_r), true


__all__ = ["FusionCase", "OdomNoise", "START_NS", "simulate_case"]
