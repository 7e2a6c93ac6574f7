"""Correct the IMU-propagated state with a scan-matching pose: error-state EKF or complementary filter.

EKF (lecture, 'Extended Kalman Filter'): the error state [dtheta, dp, dv, dbg, dba, dg] (18) with covariance P
from propagation; the measurement is the registered pose, residual ``(log(R_hat^T R_meas), p_meas - p_hat)``,
with noise inflated along directions the scan geometry leaves unconstrained. The update corrects pose,
velocity and both biases, which then prime the next scan.

Complementary filter (lecture): ``x_fused = alpha * x_scan + (1 - alpha) * x_pred`` on the pose (on SO(3)
by scaling the rotation residual), the position correction spread into the velocity, and a slow gyro-bias
correction from the rotation residual.
"""

from __future__ import annotations

import numpy as np

from ...geometry import skew, so3_exp_one, so3_log_one
from ..imu import STATE_DIM, NavState


def pose_residual(state: NavState, T_meas: np.ndarray) -> np.ndarray:
    """(dtheta, dp): rotation error in the body frame (right perturbation) and position error in world."""
    return np.concatenate([so3_log_one(state.R.T @ T_meas[:3, :3]), T_meas[:3, 3] - state.p])


def position_noise(sigma_m: float, degenerate_dirs_world: list[np.ndarray], degenerate_sigma_m: float) -> np.ndarray:
    """3x3 position covariance: isotropic, with ``degenerate_sigma_m`` along each degenerate direction."""
    C = np.eye(3) * sigma_m**2
    for d in degenerate_dirs_world:
        C += (degenerate_sigma_m**2 - sigma_m**2) * np.outer(d, d)
    return C


def _inject(state: NavState, dx: np.ndarray) -> None:
    state.R = state.R @ so3_exp_one(dx[0:3])
    state.p = state.p + dx[3:6]
    state.v = state.v + dx[6:9]
    state.bg = state.bg + dx[9:12]
    state.ba = state.ba + dx[12:15]
    g = state.g + dx[15:18]  # the direction is estimated, the magnitude is known
    state.g = g * (np.linalg.norm(state.g) / np.linalg.norm(g))


def _kalman_update(state: NavState, H: np.ndarray, r: np.ndarray, Rn: np.ndarray) -> np.ndarray:
    P = state.P
    S = H @ P @ H.T + Rn
    K = np.linalg.solve(S, H @ P).T  # P H^T S^-1 (S symmetric)
    dx = K @ r
    IKH = np.eye(STATE_DIM) - K @ H
    state.P = IKH @ P @ IKH.T + K @ Rn @ K.T
    _inject(state, dx)
    return dx


def _pose_model(rot_sigma_rad: float, pos_cov: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    H = np.zeros((6, STATE_DIM))
    H[0:3, 0:3] = np.eye(3)
    H[3:6, 3:6] = np.eye(3)
    Rn = np.zeros((6, 6))
    Rn[0:3, 0:3] = np.eye(3) * rot_sigma_rad**2
    Rn[3:6, 3:6] = pos_cov
    return H, Rn


def ekf_pose_update(state: NavState, T_meas: np.ndarray, rot_sigma_rad: float, pos_cov: np.ndarray) -> np.ndarray:
    """EKF update of ``state`` in place with a measured pose; returns the applied error-state correction."""
    H, Rn = _pose_model(rot_sigma_rad, pos_cov)
    return _kalman_update(state, H, pose_residual(state, T_meas), Rn)


def pose_innovation_nis(state: NavState, T_meas: np.ndarray, rot_sigma_rad: float, pos_cov: np.ndarray) -> float:
    """Normalised innovation squared ``r^T S^-1 r`` of a pose measurement (chi-square, 6 dof, if consistent)."""
    H, Rn = _pose_model(rot_sigma_rad, pos_cov)
    r = pose_residual(state, T_meas)
    return float(r @ np.linalg.solve(H @ state.P @ H.T + Rn, r))


def ekf_body_velocity_update(state: NavState, v_body_mps: np.ndarray, sigmas_mps: np.ndarray) -> np.ndarray:
    """EKF update with a velocity measured in the base frame (wheel odometry: forward speed, no side slip)."""
    vb = state.R.T @ state.v
    H = np.zeros((3, STATE_DIM))
    H[:, 0:3] = skew(vb)
    H[:, 6:9] = state.R.T
    return _kalman_update(state, H, v_body_mps - vb, np.diag(np.asarray(sigmas_mps) ** 2))


def complementary_velocity_update(state: NavState, v_body_mps: np.ndarray, beta: float) -> None:
    """Blend a measured base-frame velocity (wheels) into the state's: ``v = beta * v_meas + (1 - beta) * v``."""
    vb = state.R.T @ state.v
    state.v = state.R @ ((1.0 - beta) * vb + beta * np.asarray(v_body_mps, dtype=np.float64))


def complementary_update(state: NavState, T_meas: np.ndarray, alpha: float, dt_s: float, R_base_imu: np.ndarray,
                         degenerate_dirs_world: list[np.ndarray], bias_gain: float = 0.1) -> np.ndarray:
    """Blend the predicted and measured pose with weight ``alpha`` on the scan; correct velocity and gyro bias."""
    r = pose_residual(state, T_meas)
    dtheta, dp = alpha * r[0:3], alpha * r[3:6]
    for d in degenerate_dirs_world:  # no information along d: keep the prediction there
        dp = dp - d * (d @ dp)
    state.R = state.R @ so3_exp_one(dtheta)
    state.p = state.p + dp
    if dt_s > 0:
        state.v = state.v + dp / dt_s
        # a rotation residual accumulated over dt means the gyro read too much by residual/dt (base axes)
        state.bg = state.bg - bias_gain * (R_base_imu.T @ (r[0:3] / dt_s))
    return np.concatenate([dtheta, dp])
