"""Start (and restart) the IMU state from LiDAR-only poses: standing still or already moving.

An IMU alone cannot tell a platform standing still from one cruising at constant velocity, and takes the
mean specific force of an accelerating one for gravity. So the first scans (and the scans after a lost
track) are registered LiDAR-only, and their poses are aligned with the IMU over the window (the linear
alignment of visual- and LiDAR-inertial initialisation):

- gyro bias: the rotation increments between scans from the gyro must equal the LiDAR's;
- velocity and gravity: between scans k and k+1 with the IMU preintegrated from the LiDAR orientation at
  t_k (``alpha_k``, ``beta_k``: position and velocity change from the specific force alone),
  ``p_k+1 - p_k - alpha_k - B_k dt_k = v_0 dt_k + g (tau_k dt_k + dt_k^2 / 2)``, linear in (v_0, g), where
  ``tau_k = t_k - t_0`` and ``B_k`` sums the earlier ``beta``; |g| is then fixed to the known magnitude;
- wheel speed, when there is some, adds rows ``e_x . R_k^T v_k = v_wheel`` (it is what makes a moving start
  in a featureless corridor observable).

The platform counts as standing still only when the LiDAR, the IMU and the wheels (if any) all agree; then
gravity and gyro bias come from the IMU means, which are sharper than any alignment.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ...geometry import so3_log
from ...model.calibration import Extrinsics
from ...model.records import ImuBatch
from ..imu import NavState, propagate

STILL_TRANSLATION_M = 0.03  # LiDAR: the window's poses stay within this of the first (registration noise
STILL_ROTATION_RAD = np.radians(1.0)  # of a sparse LiDAR-only scan reaches a centimetre and half a degree)
STILL_GYRO_RADPS = 0.05  # IMU: spread of the gyro around its mean
STILL_ACCEL_MPS2 = 0.3  # IMU: spread of the specific-force norm around gravity
STILL_WHEEL_MPS = 0.03
POSITION_SIGMA_M = 0.03  # LiDAR-only registration, per scan
ROTATION_SIGMA_RAD = 0.003  # LiDAR-only registration, rotation increment between scans
GYRO_BIAS_PRIOR_RADPS = 0.005  # a MEMS gyro's bias is rarely larger; keeps a short window from inventing one
WHEEL_SIGMA_MPS = 0.05
GRAVITY_TOLERANCE = 0.25  # an unconstrained gravity estimate further than this (relative) from g is not trusted


@dataclass(frozen=True)
class Bootstrap:
    """The IMU state at the window's last scan, in the LiDAR's world frame."""

    static: bool
    stamp_ns: int  # the window's last scan
    v_world: np.ndarray  # velocity at the window's last scan
    v_start: np.ndarray  # velocity at the window's first scan
    g_world: np.ndarray  # gravity in the world frame, |g| = the configured magnitude
    gyro_bias: np.ndarray  # IMU frame
    scans: int
    reason: str
    gravity_aligned: bool = True  # False: too little excitation, gravity is the window's mean specific force
    residual_m: float = 0.0  # RMS misfit of the LiDAR-only position increments to the IMU over the window


def lidar_still(poses: np.ndarray) -> bool:
    """The window's poses (N,4,4) stay within a few centimetres and tenths of a degree of the first."""
    rel = np.einsum("ji,njk->nik", poses[0, :3, :3], poses[:, :3, :3])
    angles = np.linalg.norm(so3_log(rel), axis=-1)
    shifts = np.linalg.norm(poses[:, :3, 3] - poses[0, :3, 3], axis=1)
    return bool(shifts.max() < STILL_TRANSLATION_M and angles.max() < STILL_ROTATION_RAD)


def imu_still(imu: ImuBatch, gravity_mps2: float, accel_bias: np.ndarray) -> bool:
    if len(imu) < 3:
        return False
    gyro_dev = np.linalg.norm(imu.gyro_radps - imu.gyro_radps.mean(axis=0), axis=1).max()
    accel_dev = np.abs(np.linalg.norm(imu.accel_mps2 - accel_bias, axis=1) - gravity_mps2).max()
    return bool(gyro_dev < STILL_GYRO_RADPS and accel_dev < STILL_ACCEL_MPS2)


def _window(imu: ImuBatch, t0_ns: int, t1_ns: int) -> ImuBatch:
    sel = (imu.stamps_ns >= t0_ns) & (imu.stamps_ns <= t1_ns)
    return ImuBatch(imu.frame_id, imu.stamps_ns[sel], imu.gyro_radps[sel], imu.accel_mps2[sel])


def _increments(stamps_ns: np.ndarray, poses: np.ndarray, imu: ImuBatch, ext: Extrinsics, bg: np.ndarray,
                ba: np.ndarray) -> list:
    """Per interval: the state reached from (R_k, p=0, v=0) with the specific force alone (no gravity)."""
    out = []
    zero = np.zeros(3)
    for k in range(len(stamps_ns) - 1):
        s0 = NavState(int(stamps_ns[k]), poses[k, :3, :3].copy(), zero.copy(), zero.copy(), bg, ba)
        out.append(propagate(s0, imu, int(stamps_ns[k + 1]), ext, g_world=zero).state)
    return out


def _rotation_residuals(stamps_ns, poses, imu, ext, bg, ba) -> np.ndarray:
    """(K-1)*3 rotation differences (rad) between the gyro's and the LiDAR's increments."""
    inc = _increments(stamps_ns, poses, imu, ext, bg, ba)
    return np.concatenate([so3_log(poses[k + 1, :3, :3].T @ s.R) for k, s in enumerate(inc)])


def estimate_gyro_bias(stamps_ns: np.ndarray, poses: np.ndarray, imu: ImuBatch, ext: Extrinsics,
                       bg0: np.ndarray, ba: np.ndarray, iterations: int = 2) -> np.ndarray:
    """Gyro bias (IMU frame) that makes the gyro's rotation increments match the LiDAR's (Gauss-Newton).

    A zero-mean prior of ``GYRO_BIAS_PRIOR_RADPS`` weighs against the LiDAR's rotation noise, so a short or
    noisy window leaves the bias near zero for the filter to refine, instead of inventing one.
    """
    bg = np.asarray(bg0, dtype=np.float64).copy()
    eps = 1e-4
    prior = np.eye(3) / GYRO_BIAS_PRIOR_RADPS
    for _ in range(iterations):
        r0 = _rotation_residuals(stamps_ns, poses, imu, ext, bg, ba)
        J = np.stack([(_rotation_residuals(stamps_ns, poses, imu, ext, bg + eps * e, ba) - r0) / eps
                      for e in np.eye(3)], axis=1)
        A = np.vstack([J / ROTATION_SIGMA_RAD, prior])
        b = np.concatenate([-r0 / ROTATION_SIGMA_RAD, -prior @ bg])
        step, *_ = np.linalg.lstsq(A, b, rcond=None)
        bg = bg + step
        if np.linalg.norm(step) < 1e-6:
            break
    return bg


def align(stamps_ns: np.ndarray, poses: np.ndarray, imu: ImuBatch, ext: Extrinsics, *, gravity_mps2: float,
          accel_bias: np.ndarray, gyro_bias: np.ndarray | None = None, g_world: np.ndarray | None = None,
          wheel_speeds: np.ndarray | None = None, planar: bool = False) -> Bootstrap:
    """The IMU state at ``stamps_ns[-1]`` from LiDAR-only poses (N,4,4) of the base over the window.

    ``gyro_bias``: a known bias (a calibration) is kept, else estimated. ``g_world``: gravity when already
    known (a restart after a lost track; planar mode), else estimated. ``wheel_speeds``: forward speed at each
    stamp (NaN where none).
    """
    ba = np.asarray(accel_bias, dtype=np.float64)
    stamps_ns = np.asarray(stamps_ns, dtype=np.int64)
    n = len(stamps_ns)
    win = _window(imu, int(stamps_ns[0]), int(stamps_ns[-1]))
    wheel_still = wheel_speeds is None or not np.isfinite(wheel_speeds).any() or \
        np.nanmax(np.abs(wheel_speeds)) < STILL_WHEEL_MPS
    if lidar_still(poses) and imu_still(win, gravity_mps2, ba) and wheel_still:
        f_world = poses[0, :3, :3] @ ext.R_base_imu @ (win.accel_mps2.mean(axis=0) - ba)
        g = -gravity_mps2 * f_world / np.linalg.norm(f_world) if g_world is None else np.asarray(g_world)
        bg = win.gyro_radps.mean(axis=0) if gyro_bias is None else np.asarray(gyro_bias, dtype=np.float64)
        return Bootstrap(True, int(stamps_ns[-1]), np.zeros(3), np.zeros(3), g, bg, n,
                         f"standing start: LiDAR, IMU{' and wheels' if wheel_speeds is not None else ''} agree on "
                         f"no motion over {n} scans; gravity and gyro bias from {len(win)} IMU samples")
    bg = estimate_gyro_bias(stamps_ns, poses, imu, ext, np.zeros(3), ba) if gyro_bias is None \
        else np.asarray(gyro_bias, dtype=np.float64)
    inc = _increments(stamps_ns, poses, imu, ext, bg, ba)
    dts = np.diff(stamps_ns) * 1e-9
    tau = np.concatenate([[0.0], np.cumsum(dts)])
    B = np.vstack([np.zeros(3), np.cumsum([s.v for s in inc], axis=0)])  # sum of earlier beta
    rows, rhs = [], []
    I3 = np.eye(3)
    for k in range(n - 1):  # positions, weighted by 1/sigma
        dp = poses[k + 1, :3, 3] - poses[k, :3, 3] - inc[k].p - B[k] * dts[k]
        rows.append(np.hstack([I3 * dts[k], I3 * (tau[k] * dts[k] + 0.5 * dts[k] ** 2)]) / POSITION_SIGMA_M)
        rhs.append(dp / POSITION_SIGMA_M)
    if wheel_speeds is not None:
        for k in np.flatnonzero(np.isfinite(wheel_speeds)):  # forward body speed, no side slip
            ex = poses[k, :3, :3][:, 0]
            rows.append(np.hstack([ex, ex * tau[k]])[None] / WHEEL_SIGMA_MPS)
            rhs.append(np.array([wheel_speeds[k] - ex @ B[k]]) / WHEEL_SIGMA_MPS)
    A, b = np.vstack(rows), np.concatenate(rhs)
    aligned = True
    if g_world is None:
        x, *_ = np.linalg.lstsq(A, b, rcond=None)
        g_free = x[3:]
        if abs(np.linalg.norm(g_free) / gravity_mps2 - 1.0) > GRAVITY_TOLERANCE:
            aligned = False
            # too little excitation to separate gravity from acceleration: the mean specific force points up
            g_free = -(poses[0, :3, :3] @ ext.R_base_imu @ (win.accel_mps2.mean(axis=0) - ba))
        g = gravity_mps2 * g_free / np.linalg.norm(g_free)
    else:
        g = np.asarray(g_world, dtype=np.float64)
    v0, *_ = np.linalg.lstsq(A[:, :3], b - A[:, 3:] @ g, rcond=None)
    if planar:
        v0[2] = 0.0
    v_end = v0 + g * tau[-1] + B[-1]
    speed = float(np.linalg.norm(v_end))
    misfit = (A[:3 * (n - 1)] @ np.concatenate([v0, g]) - b[:3 * (n - 1)]).reshape(-1, 3) * POSITION_SIGMA_M
    residual = float(np.sqrt(np.mean(np.sum(misfit**2, axis=1))))
    return Bootstrap(False, int(stamps_ns[-1]), v_end, v0, g, bg, n,
                     f"moving start: velocity {speed:.2f} m/s, gravity and gyro bias aligned from {n} LiDAR-only "
                     f"scans over {tau[-1]:.2f} s", aligned, residual)
