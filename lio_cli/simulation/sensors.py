"""Sensor models (the lecture's): spinning LiDAR and 2D laser scanner with motion skew, IMU with lever arm,
biases and noise, differential-drive wheel odometry with scale errors and slip.

All functions are pure: they take the trajectory, the world and a seeded ``numpy.random.Generator`` and
return arrays; nothing here writes files. Sensor stamps are integer ns; the trajectory is evaluated at
``(stamp_ns - start_ns) * 1e-9`` seconds.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from ..model.records import on_lidar_clock
from .motion import Trajectory
from .world import World, raycast

GRAVITY_MPS2 = np.array([0.0, 0.0, -9.81])
NS = 1_000_000_000


def beam_elevations_deg(beams: int) -> np.ndarray:
    """Elevation angles of a spinning LiDAR's beams, lowest first (16: +-15 deg, 32/64: -25..+15,
    128: +-22.5)."""
    lo, hi = {16: (-15.0, 15.0), 32: (-25.0, 15.0), 64: (-25.0, 15.0), 128: (-22.5, 22.5)}.get(beams, (-15.0, 15.0))
    return np.linspace(lo, hi, beams)


@dataclass
class LidarSpec:
    """A spinning multi-beam LiDAR. Column c of a sweep is fired at ``start + c * period / columns``;
    azimuth grows counter-clockwise from -pi (the seam is behind the sensor)."""

    beams: int = 16
    columns: int = 1024
    period_ns: int = 100_000_000
    min_range_m: float = 0.4
    max_range_m: float = 100.0
    range_noise_m: float = 0.015
    dropout: float = 0.01
    elevations_deg: np.ndarray | None = None

    def directions(self) -> np.ndarray:
        """Unit ray directions in the sensor frame, (columns, beams, 3)."""
        elev = np.radians(self.elevations_deg if self.elevations_deg is not None else beam_elevations_deg(self.beams))
        az = -np.pi + 2.0 * np.pi * np.arange(self.columns) / self.columns
        ce, se = np.cos(elev)[None, :], np.sin(elev)[None, :]
        return np.stack([np.cos(az)[:, None] * ce, np.sin(az)[:, None] * ce, np.broadcast_to(se, (self.columns, len(elev)))], axis=-1)

    def column_offsets_ns(self) -> np.ndarray:
        return (np.arange(self.columns, dtype=np.int64) * self.period_ns) // self.columns


@dataclass
class Scan:
    """One simulated sweep: points in the sensor frame at their own capture instants (skewed by motion).

    Only valid returns are kept, in firing order (column-major). ``stamps_ns`` absolute, ``ring`` the beam
    index (0 = lowest), ``intensity`` 0..255, ``ranges_true_m`` the noiseless ranges of the kept points.
    """

    start_ns: int
    end_ns: int
    points: np.ndarray
    stamps_ns: np.ndarray
    ring: np.ndarray
    intensity: np.ndarray
    ranges_true_m: np.ndarray


def spin_scan(world: World, traj: Trajectory, T_base_lidar: np.ndarray, spec: LidarSpec, start_ns: int,
              traj_start_ns: int, rng: np.random.Generator | None = None, frozen_ns: int | None = None) -> Scan:
    """Simulate one sweep starting at ``start_ns``. Each column is cast from the sensor pose at its own
    firing time (``frozen_ns``: every column from the pose at that one instant instead: a sensor standing
    still). Noise and dropouts come from ``rng`` (None: noiseless, no dropouts)."""
    dirs_l = spec.directions()  # (C,B,3)
    C, B = dirs_l.shape[:2]
    col_ns = start_ns + spec.column_offsets_ns()
    pose_ns = col_ns if frozen_ns is None else np.full(C, frozen_ns, np.int64)
    T_wb = traj.poses((pose_ns - traj_start_ns) * 1e-9)
    T_wl = T_wb @ T_base_lidar
    dirs_w = np.matmul(dirs_l, np.swapaxes(T_wl[:, :3, :3], 1, 2))  # (C,B,3): each column rotated by its pose
    origins = np.broadcast_to(T_wl[:, None, :3, 3], (C, B, 3))
    r_true, prim = raycast(world, origins.reshape(-1, 3), dirs_w.reshape(-1, 3), spec.max_range_m)
    r = r_true.copy()
    valid = np.isfinite(r) & (r >= spec.min_range_m)
    if rng is not None:
        r = r + rng.normal(0.0, 1.0, len(r)) * spec.range_noise_m
        valid &= rng.random(len(r)) >= spec.dropout
    refl = world.reflectivity
    pts = dirs_l.reshape(-1, 3)[valid] * r[valid, None]
    ring = np.broadcast_to(np.arange(B, dtype=np.uint16)[None, :], (C, B)).reshape(-1)[valid]
    stamps = np.broadcast_to(col_ns[:, None], (C, B)).reshape(-1)[valid]
    inten = np.clip(255.0 * refl[prim[valid]] * np.minimum(1.0, 8.0 / np.maximum(r_true[valid], 1.0)) ** 0.5, 0.0, 255.0)
    return Scan(int(start_ns), int(start_ns + spec.period_ns), pts, stamps, ring, inten.astype(np.float32),
                r_true[valid])


@dataclass
class LaserSpec:
    """A 2D scanner sweeping counter-clockwise from ``angle_min`` over one period (like a LaserScan)."""

    beams: int = 720
    angle_min_rad: float = -np.pi
    period_ns: int = 100_000_000
    min_range_m: float = 0.1
    max_range_m: float = 30.0
    range_noise_m: float = 0.01
    dropout: float = 0.01

    @property
    def angle_increment_rad(self) -> float:
        return 2.0 * np.pi / self.beams

    @property
    def time_increment_s(self) -> float:
        return self.period_ns * 1e-9 / self.beams


def laser_scan(world: World, traj: Trajectory, T_base_lidar: np.ndarray, spec: LaserSpec, start_ns: int,
               traj_start_ns: int, rng: np.random.Generator | None = None) -> np.ndarray:
    """Ranges (beams,) float32 of one 2D sweep, each beam from the sensor pose at its own time; +inf for
    no return within range (REP 117), NaN for a dropout."""
    k = np.arange(spec.beams)
    beam_ns = start_ns + (k * spec.period_ns) // spec.beams
    ang = spec.angle_min_rad + k * spec.angle_increment_rad
    dirs_l = np.stack([np.cos(ang), np.sin(ang), np.zeros_like(ang)], axis=1)
    T_wl = traj.poses((beam_ns - traj_start_ns) * 1e-9) @ T_base_lidar
    dirs_w = np.einsum("nij,nj->ni", T_wl[:, :3, :3], dirs_l)
    r, _ = raycast(world, T_wl[:, :3, 3], dirs_w, spec.max_range_m)
    if rng is not None:
        r = r + rng.normal(0.0, 1.0, len(r)) * spec.range_noise_m
        r[rng.random(len(r)) < spec.dropout] = np.nan
    r[r < spec.min_range_m] = np.inf
    return r.astype(np.float32)


@dataclass
class ImuSpec:
    """IMU errors. Noise densities are continuous-time (per sqrt(Hz)); the discrete white-noise std is
    density * sqrt(rate). Biases: constant initial value plus a random walk with the given density.
    ``imu_time_offset_ns`` is added to IMU stamps to put them on the LiDAR's (true) clock: true sampling instant
    = stamp + offset (the IMU clock lags when > 0)."""

    rate_hz: float = 200.0
    accel_noise_density: float = 2.0e-3  # m/s^2/sqrt(Hz)
    gyro_noise_density: float = 1.7e-4  # rad/s/sqrt(Hz)
    accel_bias_walk: float = 3.0e-4  # m/s^3/sqrt(Hz)
    gyro_bias_walk: float = 2.0e-5  # rad/s^2/sqrt(Hz)
    accel_bias0_mps2: np.ndarray = field(default_factory=lambda: np.zeros(3))
    gyro_bias0_radps: np.ndarray = field(default_factory=lambda: np.zeros(3))
    imu_time_offset_ns: int = 0


@dataclass
class ImuData:
    stamps_ns: np.ndarray  # (N,) as stamped by the IMU clock
    gyro_radps: np.ndarray  # (N,3) in the imu frame
    accel_mps2: np.ndarray  # (N,3) specific force in the imu frame
    accel_bias_mps2: np.ndarray  # (N,3) the true bias at each sample
    gyro_bias_radps: np.ndarray  # (N,3)


def imu_truth(traj: Trajectory, T_base_imu: np.ndarray, t_s: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Ideal (gyro, specific force) of the imu frame at times ``t_s``: omega_imu = R_bi^T omega_b and
    f = R_wi^T (a_imu - g) with a_imu = a_base + R_wb (alpha x r + omega x (omega x r)), r the lever arm."""
    st = traj.state(t_s)
    R_bi, r = T_base_imu[:3, :3], T_base_imu[:3, 3]
    w, al = st.omega_base_radps, st.alpha_base_radps2
    lever_b = np.cross(al, r) + np.cross(w, np.cross(w, r[None, :]))
    a_imu_w = st.accel_mps2 + np.einsum("nij,nj->ni", st.R_world_base, lever_b)
    f_base = np.einsum("nji,nj->ni", st.R_world_base, a_imu_w - GRAVITY_MPS2)
    return w @ R_bi, f_base @ R_bi


def synthesize_imu(traj: Trajectory, T_base_imu: np.ndarray, spec: ImuSpec, start_ns: int, end_ns: int,
                   traj_start_ns: int, rng: np.random.Generator | None, continue_walk: bool = False) -> ImuData:
    """IMU samples stamped on a regular grid from ``start_ns`` to ``end_ns`` (inclusive) of the IMU clock;
    the true sampling instant of stamp s is ``s + imu_time_offset_ns``. ``rng`` None: no noise, no walk.
    The first sample's bias is ``spec``'s initial bias, or (``continue_walk``, for the next piece of a run
    made in pieces) one random-walk step after it."""
    period_ns = int(round(NS / spec.rate_hz))
    stamps = np.arange(start_ns, end_ns + 1, period_ns, dtype=np.int64)
    t_true = (on_lidar_clock(stamps, spec.imu_time_offset_ns) - traj_start_ns) * 1e-9
    gyro, accel = imu_truth(traj, T_base_imu, t_true)
    n, dt = len(stamps), period_ns * 1e-9
    ba = np.broadcast_to(np.asarray(spec.accel_bias0_mps2, float), (n, 3)).copy()
    bg = np.broadcast_to(np.asarray(spec.gyro_bias0_radps, float), (n, 3)).copy()
    if rng is not None:
        walk_a = rng.normal(0.0, 1.0, (n, 3)) * spec.accel_bias_walk * np.sqrt(dt)
        walk_g = rng.normal(0.0, 1.0, (n, 3)) * spec.gyro_bias_walk * np.sqrt(dt)
        if not continue_walk:
            walk_a[0] = walk_g[0] = 0.0
        ba += np.cumsum(walk_a, axis=0)
        bg += np.cumsum(walk_g, axis=0)
        noise_a = rng.normal(0.0, 1.0, (n, 3)) * spec.accel_noise_density / np.sqrt(dt)
        noise_g = rng.normal(0.0, 1.0, (n, 3)) * spec.gyro_noise_density / np.sqrt(dt)
    else:
        noise_a = noise_g = np.zeros((n, 3))
    return ImuData(stamps, gyro + bg + noise_g, accel + ba + noise_a, ba, bg)


@dataclass
class WheelSpec:
    """Differential drive. Odometry uses the nominal radius and baseline; the true ones differ by the
    scale factors (true = nominal * scale). During the slip window both wheels turn faster than the ground
    moves under them (measured speed * (1 + slip)); ``bursts`` adds more such windows, each
    (start_s, duration_s, slip_left, slip_right)."""

    rate_hz: float = 50.0
    radius_m: float = 0.1
    baseline_m: float = 0.5
    radius_scale_left: float = 1.0
    radius_scale_right: float = 1.0
    baseline_scale: float = 1.0
    slip_start_s: float | None = None
    slip_duration_s: float = 0.0
    slip_left: float = 0.0
    slip_right: float = 0.0
    bursts: tuple[tuple[float, float, float, float], ...] = ()
    substeps: int = 20


@dataclass
class WheelOdometry:
    stamps_ns: np.ndarray  # (N,)
    poses_odom_base: np.ndarray  # (N,4,4), identity at the first stamp
    linear_mps: np.ndarray  # (N,) forward speed estimate in the base frame
    angular_radps: np.ndarray  # (N,) yaw rate estimate


def wheel_odometry(traj: Trajectory, spec: WheelSpec, start_ns: int, end_ns: int, traj_start_ns: int) -> WheelOdometry:
    """Integrate diff-drive odometry (lecture: v = (vR+vL)/2, w = (vR-vL)/L) from the true wheel speeds
    as the encoders would report them, ``substeps`` exact-arc updates per published message."""
    period_ns = int(round(NS / spec.rate_hz))
    stamps = np.arange(start_ns, end_ns + 1, period_ns, dtype=np.int64)
    k = spec.substeps
    fine_ns = start_ns + np.arange((len(stamps) - 1) * k + 1, dtype=np.int64) * period_ns // k
    t = (fine_ns - traj_start_ns) * 1e-9
    st = traj.state(t)
    R = st.R_world_base
    v = np.einsum("ni,ni->n", st.velocity_mps, R[:, :, 0])  # forward speed of the base origin
    w = st.omega_base_radps[:, 2]  # yaw rate (wheeled platforms stay level, or nearly)
    L_true = spec.baseline_m * spec.baseline_scale
    vR, vL = v + w * L_true / 2.0, v - w * L_true / 2.0
    slip_R = slip_L = np.zeros_like(t)
    if spec.slip_start_s is not None and spec.slip_duration_s > 0:
        win = smooth_window(t, spec.slip_start_s, spec.slip_duration_s)
        slip_R, slip_L = spec.slip_right * win, spec.slip_left * win
    for b_start, b_dur, b_left, b_right in spec.bursts:
        win = smooth_window(t, b_start, b_dur)
        slip_R, slip_L = slip_R + b_right * win, slip_L + b_left * win
    # encoder wheel rates -> speeds with the nominal radius
    vR_est = vR * (1.0 + slip_R) / spec.radius_scale_right
    vL_est = vL * (1.0 + slip_L) / spec.radius_scale_left
    v_est = 0.5 * (vR_est + vL_est)
    w_est = (vR_est - vL_est) / spec.baseline_m
    # exact-arc integration with the interval's mean speeds (trapezoid of encoder increments)
    dt = np.diff(t)
    dv = 0.5 * (v_est[1:] + v_est[:-1]) * dt
    dth = 0.5 * (w_est[1:] + w_est[:-1]) * dt
    th = np.concatenate([[0.0], np.cumsum(dth)])
    mid = th[:-1] + 0.5 * dth
    x = np.concatenate([[0.0], np.cumsum(dv * np.cos(mid) * _sinc(0.5 * dth))])
    y = np.concatenate([[0.0], np.cumsum(dv * np.sin(mid) * _sinc(0.5 * dth))])
    idx = np.arange(len(stamps)) * k
    T = np.zeros((len(stamps), 4, 4))
    c, s = np.cos(th[idx]), np.sin(th[idx])
    T[:, 0, 0], T[:, 0, 1], T[:, 1, 0], T[:, 1, 1] = c, -s, s, c
    T[:, 2, 2] = T[:, 3, 3] = 1.0
    T[:, 0, 3], T[:, 1, 3] = x[idx], y[idx]
    return WheelOdometry(stamps, T, v_est[idx], w_est[idx])


def _sinc(x: np.ndarray) -> np.ndarray:
    return np.sinc(x / np.pi)


def slip_bursts(count: int, rest_s: float, duration_s: float, rng: np.random.Generator) -> tuple:
    """``count`` slip bursts spread over the moving part of a run: 1-2.5 s each, one per equal share of the
    time (placed at random inside it), each wheel slipping 0.1-0.4 (wet grass, gravel)."""
    span = max(duration_s - rest_s, 0.0) / max(count, 1)
    bursts = []
    for k in range(count):
        dur = min(float(rng.uniform(1.0, 2.5)), 0.8 * span)
        start = rest_s + k * span + float(rng.uniform(0.1 * span, max(0.9 * span - dur, 0.1 * span)))
        left, right = (float(v) for v in rng.uniform(0.1, 0.4, 2))
        bursts.append((round(start, 6), round(dur, 6), round(left, 6), round(right, 6)))
    return tuple(bursts)


def smooth_window(t: np.ndarray, start_s: float, duration_s: float) -> np.ndarray:
    """1 inside [start, start + duration] with raised-cosine edges of 10% of the duration, 0 outside."""
    edge = max(0.1 * duration_s, 1e-3)
    x = np.asarray(t, float)
    up = np.clip((x - start_s) / edge, 0.0, 1.0)
    down = np.clip((start_s + duration_s - x) / edge, 0.0, 1.0)
    return 0.5 * (1 - np.cos(np.pi * np.minimum(up, down)))
