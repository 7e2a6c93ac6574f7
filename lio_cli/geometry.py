"""SO(3), SE(3) and SE(2) helpers on numpy arrays.

Conventions (DESIGN.md): poses are float64 (4,4) or (N,4,4); ``T_a_b`` maps points from frame b to frame a;
quaternions are xyzw. This is the only module that touches ``scipy.spatial.transform.Rotation``, and only
when a function needs it: importing scipy.spatial costs about half a second, which a short command such as
``lio evaluate`` would otherwise spend before any work. ``so3_log_batch`` and ``quat_xyzw_to_rot`` are scipy's
own algorithms written out in numpy (they agree with it to the last bit or two).
"""

from __future__ import annotations

import math

import numpy as np

_SMALL_ANGLE_RAD = 1e-8


def skew(v: np.ndarray) -> np.ndarray:
    """The cross-product matrix [v]x of a 3-vector (or (N,3) -> (N,3,3))."""
    v = np.asarray(v, dtype=np.float64)
    out = np.zeros(v.shape[:-1] + (3, 3))
    out[..., 0, 1], out[..., 0, 2] = -v[..., 2], v[..., 1]
    out[..., 1, 0], out[..., 1, 2] = v[..., 2], -v[..., 0]
    out[..., 2, 0], out[..., 2, 1] = -v[..., 1], v[..., 0]
    return out


_EYE3 = np.eye(3)
_ORTHO_TOL = 1e-12 + 1e-5 * _EYE3  # np.isclose's atol + rtol * |I|


def _rotation():
    from scipy.spatial.transform import Rotation  # deferred: see the module's docstring

    return Rotation


def so3_exp(rotvec_rad: np.ndarray) -> np.ndarray:
    """Rotation matrix (3,3) or (N,3,3) of a rotation vector (axis * angle)."""
    return _rotation().from_rotvec(np.asarray(rotvec_rad, dtype=np.float64)).as_matrix()


def so3_log(R: np.ndarray) -> np.ndarray:
    """Rotation vector of a rotation matrix (3,3) or (N,3,3)."""
    return _rotation().from_matrix(np.asarray(R, dtype=np.float64)).as_rotvec()


def so3_log_batch(R: np.ndarray) -> np.ndarray:
    """:func:`so3_log` without scipy, for large batches and scipy-free paths (``lio evaluate``).

    scipy's ``Rotation.from_matrix(R).as_rotvec()`` in numpy (equal to it to a unit or two in the last place;
    faster from a few thousand matrices on, slower on a handful, where scipy's per-call cost is lower): a matrix that is not orthogonal to 1e-12 is
    replaced by its nearest rotation (SVD), then Shepperd's quaternion (the largest of the diagonal and the
    trace decides), then the rotation vector with the series below 1e-3 rad. A non-positive determinant
    raises ValueError, as scipy does."""
    m = np.array(R, dtype=np.float64)  # a copy: non-orthogonal matrices are replaced in place
    one = m.ndim == 2
    if one:
        m = m[None]
    if m.shape[-2:] != (3, 3):
        raise ValueError(f"Expected `matrix` to have shape (3, 3) or (N, 3, 3), got {m.shape}")
    det = np.linalg.det(m)
    if (det <= 0).any():
        i = int(np.flatnonzero(det <= 0)[0])
        raise ValueError(f"Non-positive determinant (left-handed or null coordinate frame) in rotation matrix {i}: {m[i]}.")
    gram = m @ np.swapaxes(m, -1, -2)
    gram -= _EYE3  # np.isclose(gram, I, rtol=1e-5, atol=1e-12), written out: this runs per filter step
    ortho = (np.abs(gram) <= _ORTHO_TOL).all(axis=(-2, -1))
    if not ortho.all():
        U, _, Vt = np.linalg.svd(m[~ortho], full_matrices=False)
        m[~ortho] = U @ Vt
    trace = m[:, 0, 0] + m[:, 1, 1] + m[:, 2, 2]
    choice = np.argmax(np.stack([m[:, 0, 0], m[:, 1, 1], m[:, 2, 2], trace], axis=-1), axis=-1)
    # Shepperd: the trace case (every rotation below 90 degrees) first, then the diagonal cases where chosen
    q = np.stack([m[:, 2, 1] - m[:, 1, 2], m[:, 0, 2] - m[:, 2, 0], m[:, 1, 0] - m[:, 0, 1], 1 + trace], axis=-1)
    if not (choice == 3).all():
        for c in range(3):
            sel = choice == c
            if not sel.any():
                continue
            a = m[sel]
            tr = trace[sel]
            i, j, k = c, (c + 1) % 3, (c + 2) % 3
            qc = np.empty((len(a), 4))
            qc[:, i] = 1 - tr + 2 * a[:, i, i]
            qc[:, j] = a[:, j, i] + a[:, i, j]
            qc[:, k] = a[:, k, i] + a[:, i, k]
            qc[:, 3] = a[:, k, j] - a[:, j, k]
            q[sel] = qc
    q /= np.sqrt(np.sum(q * q, axis=-1))[:, None]
    q[q[:, 3] < 0] *= -1.0  # canonical: w >= 0 (scipy's as_rotvec)
    ax_norm = np.sqrt(np.sum(q[:, :3] * q[:, :3], axis=-1))
    angle = 2 * np.arctan2(ax_norm, q[:, 3])
    small = angle <= 1e-3
    angle2 = angle**2
    with np.errstate(divide="ignore", invalid="ignore"):
        scale = np.where(small, 2 + angle2 / 12 + 7 * angle2**2 / 2880, angle / np.sin(angle / 2.0))
    out = scale[:, None] * q[:, :3]
    return out[0] if one else out


def quat_xyzw_to_rot(quat_xyzw: np.ndarray) -> np.ndarray:
    """Rotation matrix from quaternion(s) in xyzw order (normalised on the way); scipy's ``from_quat``
    + ``as_matrix`` in numpy. A zero quaternion raises ValueError, as scipy does."""
    q = np.asarray(quat_xyzw, dtype=np.float64)
    if q.shape[-1] != 4 or q.ndim not in (1, 2):
        raise ValueError(f"Expected `quat` to have shape (4,) or (N, 4), got {q.shape}.")
    norm = np.sqrt(np.sum(q * q, axis=-1))
    if np.any(norm == 0):
        raise ValueError("Found zero norm quaternions in `quat`.")
    q = q / norm[..., None]
    x, y, z, w = q[..., 0], q[..., 1], q[..., 2], q[..., 3]
    x2, y2, z2, w2 = x * x, y * y, z * z, w * w
    xy, zw, xz, yw, yz, xw = x * y, z * w, x * z, y * w, y * z, x * w
    m = np.stack([x2 - y2 - z2 + w2, 2 * (xy - zw), 2 * (xz + yw),
                  2 * (xy + zw), -x2 + y2 - z2 + w2, 2 * (yz - xw),
                  2 * (xz - yw), 2 * (yz + xw), -x2 - y2 + z2 + w2], axis=-1)
    return m.reshape(q.shape[:-1] + (3, 3))


def rot_to_quat_xyzw(R: np.ndarray) -> np.ndarray:
    """Quaternion(s) xyzw of rotation matrix(es), with w >= 0."""
    q = _rotation().from_matrix(np.asarray(R, dtype=np.float64)).as_quat()
    sign = np.where(q[..., 3:4] < 0.0, -1.0, 1.0)
    return q * sign


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
