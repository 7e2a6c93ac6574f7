"""SO(3), SE(3) and SE(2) helpers on numpy arrays.

Conventions (DESIGN.md): poses are float64 (4,4) or (N,4,4); ``T_a_b`` maps points from frame b to frame a;
quaternions are xyzw. The exponential and logarithm of SO(3) and the quaternion conversions are in ``so3``
(scipy's algorithms in numpy) and are exported from here too.
"""

from __future__ import annotations

import math

import numpy as np

from .so3 import quat_xyzw_to_rot, rot_to_quat_xyzw, so3_exp, so3_log, so3_log_batch

_SMALL_ANGLE_RAD = 1e-8


def skew(v: np.ndarray) -> np.ndarray:
    """The cross-product matrix [v]x of a 3-vector (or (N,3) -> (N,3,3))."""
    v = np.asarray(v, dtype=np.float64)
    out = np.zeros(v.shape[:-1] + (3, 3))
    out[..., 0, 1], out[..., 0, 2] = -v[..., 2], v[..., 1]
    out[..., 1, 0], out[..., 1, 2] = v[..., 2], -v[..., 0]
    out[..., 2, 0], out[..., 2, 1] = -v[..., 1], v[..., 0]
    return out


def cross_rows(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """``np.cross(a, b)`` of (N,3) rows (either may be one (3,) vector): numpy's products and differences
    written out, so the same bits, without np.cross's per-call overhead (tens of microseconds)."""
    a0, a1, a2 = a[..., 0], a[..., 1], a[..., 2]
    b0, b1, b2 = b[..., 0], b[..., 1], b[..., 2]
    return np.stack([a1 * b2 - a2 * b1, a2 * b0 - a0 * b2, a0 * b1 - a1 * b0], axis=-1)


def row_norms(v: np.ndarray) -> np.ndarray:
    """Euclidean norms of the rows of an (N,3) array: ``np.linalg.norm(v, axis=1)`` to the bit (the same
    ((x^2 + y^2) + z^2) sum), about twice as fast on a scan's points, whose length-3 rows make numpy's
    reduction crawl."""
    x, y, z = v[:, 0], v[:, 1], v[:, 2]
    return np.sqrt(x * x + y * y + z * z)


def make_pose(R: np.ndarray | None = None, t: np.ndarray | None = None) -> np.ndarray:
    """A (4,4) pose from rotation R (3,3) and translation t (3,)."""
    T = np.eye(4)
    if R is not None:
        T[:3, :3] = R
    if t is not None:
        T[:3, 3] = t
    return T


def pose_from_xyz_quat(xyz: np.ndarray, quat_xyzw: np.ndarray) -> np.ndarray:
    """Pose(s) (4,4)/(N,4,4) from translation(s) and xyzw quaternion(s)."""
    xyz = np.asarray(xyz, dtype=np.float64)
    R = quat_xyzw_to_rot(quat_xyzw)
    T = np.zeros(xyz.shape[:-1] + (4, 4))
    T[..., :3, :3] = R
    T[..., :3, 3] = xyz
    T[..., 3, 3] = 1.0
    return T


def pose_from_xyz_quat_one(xyz, quat_xyzw) -> np.ndarray:
    """:func:`pose_from_xyz_quat` of ONE pose given as Python floats (a message's fields): the same operations
    in the same order on floats, so the same bits, without numpy's per-call cost on a 4-vector (an odometry or
    pose topic decodes one per message)."""
    x, y, z, w = quat_xyzw
    n = math.sqrt(((x * x + y * y) + z * z) + w * w)
    x, y, z, w = x / n, y / n, z / n, w / n
    x2, y2, z2, w2 = x * x, y * y, z * z, w * w
    xy, zw, xz, yw, yz, xw = x * y, z * w, x * z, y * w, y * z, x * w
    return np.array([[x2 - y2 - z2 + w2, 2 * (xy - zw), 2 * (xz + yw), xyz[0]],
                     [2 * (xy + zw), -x2 + y2 - z2 + w2, 2 * (yz - xw), xyz[1]],
                     [2 * (xz - yw), 2 * (yz + xw), -x2 - y2 + z2 + w2, xyz[2]],
                     [0.0, 0.0, 0.0, 1.0]])


def pose_to_xyz_quat(T: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Translation(s) and xyzw quaternion(s) of pose(s)."""
    T = np.asarray(T, dtype=np.float64)
    return T[..., :3, 3].copy(), rot_to_quat_xyzw(T[..., :3, :3])


def inv_pose(T: np.ndarray) -> np.ndarray:
    """Inverse of rigid pose(s) (4,4) or (N,4,4), using R^T."""
    T = np.asarray(T, dtype=np.float64)
    out = np.zeros_like(T)
    Rt = np.swapaxes(T[..., :3, :3], -1, -2)
    out[..., :3, :3] = Rt
    out[..., :3, 3] = -np.einsum("...ij,...j->...i", Rt, T[..., :3, 3])
    out[..., 3, 3] = 1.0
    return out


def transform_points(T: np.ndarray, points: np.ndarray) -> np.ndarray:
    """Apply one pose (4,4) to points (N,3), or per-point poses (N,4,4) to points (N,3)."""
    T = np.asarray(T, dtype=np.float64)
    points = np.asarray(points, dtype=np.float64)
    if T.ndim == 2:
        return points @ T[:3, :3].T + T[:3, 3]
    return np.einsum("nij,nj->ni", T[:, :3, :3], points) + T[:, :3, 3]


def interpolate_poses(stamps_ns: np.ndarray, poses: np.ndarray, query_ns: np.ndarray) -> np.ndarray:
    """Poses at ``query_ns`` by linear interpolation of translation and slerp of rotation.

    ``stamps_ns`` must be strictly increasing; queries outside are clamped to the ends.
    """
    stamps_ns = np.asarray(stamps_ns, dtype=np.int64)
    query_ns = np.asarray(query_ns, dtype=np.int64)
    if len(stamps_ns) == 1:
        return np.repeat(poses[:1], len(query_ns), axis=0)
    idx = np.clip(np.searchsorted(stamps_ns, query_ns, side="right") - 1, 0, len(stamps_ns) - 2)
    t0 = stamps_ns[idx]
    span = np.maximum(stamps_ns[idx + 1] - t0, 1).astype(np.float64)  # a repeated stamp: no NaN, the first pose
    alpha = np.clip((query_ns - t0).astype(np.float64) / span, 0.0, 1.0)
    P0, P1 = poses[idx], poses[idx + 1]
    rel = np.einsum("nji,njk->nik", P0[:, :3, :3], P1[:, :3, :3])
    dphi = so3_log(rel) * alpha[:, None]
    out = np.zeros((len(query_ns), 4, 4))
    out[:, :3, :3] = P0[:, :3, :3] @ so3_exp(dphi)
    out[:, :3, 3] = P0[:, :3, 3] + alpha[:, None] * (P1[:, :3, 3] - P0[:, :3, 3])
    out[:, 3, 3] = 1.0
    return out


def yaw_of(R: np.ndarray) -> np.ndarray:
    """Heading (rad) of rotation matrix(es) about world z."""
    R = np.asarray(R, dtype=np.float64)
    return np.arctan2(R[..., 1, 0], R[..., 0, 0])


def roll_pitch_yaw(R: np.ndarray) -> np.ndarray:
    """(..., 3) roll, pitch, yaw (rad) of rotation matrix(es): R = Rz(yaw) Ry(pitch) Rx(roll), pitch in [-pi/2, pi/2]."""
    R = np.asarray(R, dtype=np.float64)
    roll = np.arctan2(R[..., 2, 1], R[..., 2, 2])
    pitch = np.arcsin(np.clip(-R[..., 2, 0], -1.0, 1.0))
    return np.stack([roll, pitch, yaw_of(R)], axis=-1)


def project_to_se2(T: np.ndarray) -> np.ndarray:
    """Closest planar pose(s): keep x, y and yaw; drop z, roll and pitch."""
    T = np.asarray(T, dtype=np.float64)
    yaw = yaw_of(T[..., :3, :3])
    out = np.zeros_like(T)
    c, s = np.cos(yaw), np.sin(yaw)
    out[..., 0, 0], out[..., 0, 1], out[..., 1, 0], out[..., 1, 1] = c, -s, s, c
    out[..., 2, 2] = 1.0
    out[..., 0, 3], out[..., 1, 3] = T[..., 0, 3], T[..., 1, 3]
    out[..., 3, 3] = 1.0
    return out


def so3_exp_one(rotvec_rad: np.ndarray) -> np.ndarray:
    """Rotation matrix (3,3) of ONE rotation vector by Rodrigues' formula, without scipy's per-call overhead.

    Same result as :func:`so3_exp` for a single vector; meant for per-sample filter loops, where scipy's
    object construction (about 10 us) would dominate the step.
    """
    x, y, z = float(rotvec_rad[0]), float(rotvec_rad[1]), float(rotvec_rad[2])
    th2 = x * x + y * y + z * z
    if th2 < 1e-12:  # second-order series: exact to double precision below 1e-6 rad
        a, b = 1.0 - th2 / 6.0, 0.5 - th2 / 24.0
    else:
        th = math.sqrt(th2)
        a, b = math.sin(th) / th, (1.0 - math.cos(th)) / th2
    return np.array([
        [1.0 - b * (y * y + z * z), -a * z + b * x * y, a * y + b * x * z],
        [a * z + b * x * y, 1.0 - b * (x * x + z * z), -a * x + b * y * z],
        [-a * y + b * x * z, a * x + b * y * z, 1.0 - b * (x * x + y * y)],
    ])


def so3_log_one(R: np.ndarray) -> np.ndarray:
    """Rotation vector of ONE rotation matrix (3,3); scipy-free like :func:`so3_exp_one`.

    Angles near pi (where the antisymmetric part vanishes) fall back to :func:`so3_log`.
    """
    c = 0.5 * (float(R[0, 0] + R[1, 1] + R[2, 2]) - 1.0)
    c = 1.0 if c > 1.0 else (-1.0 if c < -1.0 else c)
    v = np.array([R[2, 1] - R[1, 2], R[0, 2] - R[2, 0], R[1, 0] - R[0, 1]])
    if c > 0.999999:  # small angle: th / (2 sin th) ~ 1/2 + th^2/12
        th2 = 2.0 * (1.0 - c)
        return v * (0.5 + th2 / 12.0)
    if c < -0.99:
        return so3_log(R)
    th = math.acos(c)
    return v * (0.5 * th / math.sin(th))


def so3_exp_scalars(x: float, y: float, z: float) -> tuple[float, ...]:
    """:func:`so3_exp_one` on three floats, returning the matrix row-major as 9 floats (no numpy call: for
    filter loops that go on with the entries as Python floats). Same formulas, same rounding."""
    th2 = x * x + y * y + z * z
    if th2 < 1e-12:
        a, b = 1.0 - th2 / 6.0, 0.5 - th2 / 24.0
    else:
        th = math.sqrt(th2)
        a, b = math.sin(th) / th, (1.0 - math.cos(th)) / th2
    return (1.0 - b * (y * y + z * z), -a * z + b * x * y, a * y + b * x * z,
            a * z + b * x * y, 1.0 - b * (x * x + z * z), -a * x + b * y * z,
            -a * y + b * x * z, a * x + b * y * z, 1.0 - b * (x * x + y * y))


def so3_log_scalars(m: list[float] | tuple[float, ...]) -> tuple[float, float, float]:
    """:func:`so3_log_one` of a rotation matrix given row-major as 9 floats; same formulas and fallback."""
    c = 0.5 * ((m[0] + m[4] + m[8]) - 1.0)
    c = 1.0 if c > 1.0 else (-1.0 if c < -1.0 else c)
    vx, vy, vz = m[7] - m[5], m[2] - m[6], m[3] - m[1]
    if c > 0.999999:
        s = 0.5 + 2.0 * (1.0 - c) / 12.0
    elif c < -0.99:
        return tuple(so3_log(np.reshape(m, (3, 3))).tolist())
    else:
        th = math.acos(c)
        s = 0.5 * th / math.sin(th)
    return vx * s, vy * s, vz * s


def gravity_aligned_rotation(f_base: np.ndarray) -> np.ndarray:
    """R_world_base whose world z is 'up' as the specific force ``f_base`` (at rest) says; yaw zero."""
    up = f_base / np.linalg.norm(f_base)
    z = np.array([0.0, 0.0, 1.0])
    axis = np.cross(up, z)
    s, c = np.linalg.norm(axis), float(up @ z)
    if s < 1e-12:
        return np.eye(3) if c > 0 else np.diag([1.0, -1.0, -1.0])
    R = so3_exp(axis / s * np.arctan2(s, c))  # rotates up (base) onto world z
    yaw = np.arctan2(R[1, 0], R[0, 0])
    Rz = so3_exp(np.array([0.0, 0.0, -yaw]))
    return Rz @ R


def axes_across(n: np.ndarray) -> np.ndarray:
    """Two orthonormal axes (rows) across the unit vector ``n``."""
    a = np.cross(n, np.eye(3)[int(np.argmin(np.abs(n)))])
    a /= np.linalg.norm(a)
    return np.stack([a, np.cross(n, a)])

