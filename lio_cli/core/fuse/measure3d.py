"""Measurement models of the 3D filter: each returns the residual ``r = z - h(x)``, its Jacobian ``H``
with respect to the error state, and the noise covariance ``Rn``.

Rotation residuals are ``log(R_hat^T R_meas)`` (base frame, matching the right-perturbation error state).
"""

from __future__ import annotations

import numpy as np

from ...geometry import so3_log_one
from .state3d import B_, DB, DP, DV, P_, TH, V_, Layout, clone_rot, rot, skew3

_EYE3 = np.eye(3)


def orientation(x: np.ndarray, R_meas: np.ndarray, cov_world: np.ndarray, L: Layout):
    """Absolute orientation ``R_world_base`` (e.g. the IMU's own estimate); ``cov_world`` about world axes."""
    R = rot(x)
    H = np.zeros((3, L.n))
    H[:, TH] = _EYE3
    return so3_log_one(R.T @ R_meas), H, R.T @ cov_world @ R


def body_velocity(x: np.ndarray, z: np.ndarray, comps: list[int], var: np.ndarray, L: Layout):
    """Components ``comps`` of the base-frame velocity ``R^T v`` (wheel odometry; 0 for the non-holonomic
    constraint)."""
    Rt = rot(x).T
    vb = Rt @ x[V_]
    H = np.zeros((len(comps), L.n))
    H[:, TH] = skew3(vb)[comps]
    H[:, DV] = Rt[comps]
    return z - vb[comps], H, np.diag(var)


def yaw_rate(x: np.ndarray, z: float, var: float, w_b: np.ndarray | None, gyro_var: float, L: Layout):
    """Body yaw rate (about base z). With a gyro model it is ``w_b_z - b_z`` (so it calibrates the gyro
    bias, and the gyro's own noise adds to the wheel's); in the ``cv`` model it is ``omega_z``."""
    H = np.zeros((1, L.n))
    if L.model == "cv":
        H[0, DB.start + 2] = 1.0
        return np.array([z - x[B_][2]]), H, np.array([[var]])
    H[0, DB.start + 2] = -1.0
    return np.array([z - (w_b[2] - x[B_][2])]), H, np.array([[var + gyro_var]])


def zero_rate(x: np.ndarray, w_b: np.ndarray, gyro_var: float, rest_var: float, L: Layout):
    """At rest (``rest``): the true rate ``w_b - b`` is zero, so the gyro's reading measures its bias (3 axes)."""
    H = np.zeros((3, L.n))
    H[:, DB] = -_EYE3
    return x[B_] - w_b, H, np.eye(3) * (gyro_var + rest_var)


def pose_absolute(x: np.ndarray, T_meas: np.ndarray, pos_var: float, rot_var: float, L: Layout):
    """A pose ``T_world_base`` in the fused world: residual ``[rotation (3), position (3)]``."""
    H = np.zeros((6, L.n))
    H[0:3, TH] = _EYE3
    H[3:6, DP] = _EYE3
    r = np.concatenate([so3_log_one(rot(x).T @ T_meas[:3, :3]), T_meas[:3, 3] - x[P_]])
    return r, H, np.diag([rot_var] * 3 + [pos_var] * 3)


def pose_delta(x: np.ndarray, T_rel: np.ndarray, pos_var: float, rot_var: float, L: Layout):
    """The increment ``T_clone^-1 T_now`` between the cloned pose and the current one (relative odometry).

    With ``M = Rc^T R`` and ``t = Rc^T (p - pc)``: rotation residual ``log(M^T R_rel)`` has Jacobian
    ``I`` on dtheta and ``-M^T`` on dtheta_c; translation residual ``t_rel - t`` has ``Rc^T`` on dp,
    ``-Rc^T`` on dp_c and ``[t]x`` on dtheta_c.
    """
    R, Rc = rot(x), clone_rot(x)
    M = Rc.T @ R
    t = Rc.T @ (x[P_] - x[30:33])
    H = np.zeros((6, L.n))
    H[0:3, TH] = _EYE3
    H[0:3, L.CTH] = -M.T
    H[3:6, DP] = Rc.T
    H[3:6, L.CP] = -Rc.T
    H[3:6, L.CTH] = skew3(t)
    r = np.concatenate([so3_log_one(M.T @ T_rel[:3, :3]), T_rel[:3, 3] - t])
    return r, H, np.diag([rot_var] * 3 + [pos_var] * 3)


def position(x: np.ndarray, p_meas: np.ndarray, cov: np.ndarray, L: Layout, lever: np.ndarray | None = None):
    """A position in the fused world (GPS after the ENU anchor) of the point ``lever`` (base axes; None: the
    base origin): ``p + R a``, whose Jacobian on the rotation error is ``-R [a]x``."""
    H = np.zeros((3, L.n))
    H[:, DP] = _EYE3
    if lever is None:
        return p_meas - x[P_], H, cov
    R = rot(x)
    H[:, TH] = -R @ skew3(lever)
    return p_meas - x[P_] - R @ lever, H, cov
