"""SO(3) exponential and logarithm and the quaternion conversions: scipy's ``Rotation`` algorithms in numpy.

``so3_exp`` is ``Rotation.from_rotvec(v).as_matrix()`` and ``so3_log`` is ``Rotation.from_matrix(R).as_rotvec()``
operation for operation (scipy's Cython loops: the same sums in the same order, the same series below 1e-3
rad), so they give scipy's bits wherever numpy's sin/cos are the C library's (x86-64 Linux; a test checks),
without importing scipy.spatial, which is slow to import at a command's start-up.
``so3_log_batch`` is ``so3_log`` with numpy's arctan2 for the angle (some results then differ from scipy's in
the last bit): faster on large batches (``lio evaluate``), where atan2 per matrix would dominate.
"""

from __future__ import annotations

import math

import numpy as np

_EYE3 = np.eye(3)
_ORTHO_TOL = 1e-12 + 1e-5 * _EYE3  # np.isclose(gram, I, atol=1e-12)'s bound: atol + rtol * |I|
_SERIES_RAD = 1e-3  # scipy's small-angle threshold for its Taylor series


def so3_exp(rotvec_rad: np.ndarray) -> np.ndarray:
    """Rotation matrix (3,3) or (N,3,3) of a rotation vector (axis * angle)."""
    v = np.asarray(rotvec_rad, dtype=np.float64)
    if v.shape[-1:] != (3,) or v.ndim not in (1, 2):
        raise ValueError(f"Expected `rot_vec` to have shape (3,) or (N, 3), got {v.shape}")
    one = v.ndim == 1
    if one:
        v = v[None]
    x, y, z = v[:, 0], v[:, 1], v[:, 2]
    angle = np.sqrt(x * x + y * y + z * z)
    half = angle / 2
    with np.errstate(invalid="ignore", divide="ignore"):
        scale = np.sin(half) / angle
    small = angle <= _SERIES_RAD
    if small.any():
        a2 = angle[small] * angle[small]
        scale[small] = 0.5 - a2 / 48 + a2 * a2 / 3840
    m = _matrix(scale * x, scale * y, scale * z, np.cos(half))
    return m[0] if one else m


def quat_xyzw_to_rot(quat_xyzw: np.ndarray) -> np.ndarray:
    """Rotation matrix from quaternion(s) in xyzw order (normalised on the way); scipy's ``from_quat`` +
    ``as_matrix``. A zero quaternion raises ValueError, as scipy does."""
    q = np.asarray(quat_xyzw, dtype=np.float64)
    if q.shape[-1] != 4 or q.ndim not in (1, 2):
        raise ValueError(f"Expected `quat` to have shape (4,) or (N, 4), got {q.shape}.")
    norm = np.sqrt(np.sum(q * q, axis=-1))
    if np.any(norm == 0):
        raise ValueError("Found zero norm quaternions in `quat`.")
    q = np.atleast_2d(q / norm[..., None])
    m = _matrix(q[:, 0], q[:, 1], q[:, 2], q[:, 3])
    return m.reshape(np.shape(quat_xyzw)[:-1] + (3, 3))


def _matrix(x: np.ndarray, y: np.ndarray, z: np.ndarray, w: np.ndarray) -> np.ndarray:
    """Rotation matrices (N,3,3) of unit quaternions given by components (scipy's ``as_matrix``)."""
    x2, y2, z2, w2 = x * x, y * y, z * z, w * w
    xy, zw, xz, yw, yz, xw = x * y, z * w, x * z, y * w, y * z, x * w
    m = np.empty((len(x), 3, 3))
    m[:, 0, 0] = x2 - y2 - z2 + w2
    m[:, 1, 0] = 2 * (xy + zw)
    m[:, 2, 0] = 2 * (xz - yw)
    m[:, 0, 1] = 2 * (xy - zw)
    m[:, 1, 1] = -x2 + y2 - z2 + w2
    m[:, 2, 1] = 2 * (yz + xw)
    m[:, 0, 2] = 2 * (xz + yw)
    m[:, 1, 2] = 2 * (yz - xw)
    m[:, 2, 2] = -x2 - y2 + z2 + w2
    return m


def so3_log(R: np.ndarray) -> np.ndarray:
    """Rotation vector of a rotation matrix (3,3) or (N,3,3); a matrix that is not orthogonal to 1e-12 is
    replaced by its nearest rotation, a non-positive determinant raises ValueError (as scipy)."""
    return _log(R, lambda s, c: np.array([math.atan2(a, b) for a, b in zip(s.tolist(), c.tolist())]))


def so3_log_batch(R: np.ndarray) -> np.ndarray:
    """:func:`so3_log` with numpy's arctan2: for large batches (equal to scipy to a unit in the last place)."""
    return _log(R, np.arctan2)


def _log(R: np.ndarray, atan2) -> np.ndarray:
    q = _quaternions(R)
    return _rotvec(q[None], atan2)[0] if q.ndim == 1 else _rotvec(q, atan2)


def _quaternions(R: np.ndarray) -> np.ndarray:
    """Unit quaternions (N,4) (or (4,) of one matrix) of rotation matrices: scipy's ``from_matrix`` (Shepperd's
    method after the orthogonality check)."""
    m = np.array(R, dtype=np.float64)  # a copy: non-orthogonal matrices are replaced in place
    one = m.ndim == 2
    if one:
        m = m[None]
    if m.ndim != 3 or m.shape[-2:] != (3, 3):
        raise ValueError(f"Expected `matrix` to have shape (3, 3) or (N, 3, 3), got {m.shape}")
    det = np.linalg.det(m)
    if (det <= 0).any():
        i = int(np.flatnonzero(det <= 0)[0])
        raise ValueError(f"Non-positive determinant (left-handed or null coordinate frame) in rotation matrix {i}: {m[i]}.")
    gram = m @ np.transpose(m, (0, 2, 1))
    gram -= _EYE3
    orthogonal = (np.abs(gram) <= _ORTHO_TOL).all(axis=(1, 2))  # np.isclose(gram, I, atol=1e-12), written out
    if not orthogonal.all():
        U, _, Vt = np.linalg.svd(m[~orthogonal])
        m[~orthogonal] = U @ Vt
    d0, d1, d2 = m[:, 0, 0], m[:, 1, 1], m[:, 2, 2]
    trace = d0 + d1 + d2
    q = np.empty((len(m), 4))
    q[:, 0], q[:, 1], q[:, 2] = m[:, 2, 1] - m[:, 1, 2], m[:, 0, 2] - m[:, 2, 0], m[:, 1, 0] - m[:, 0, 1]
    q[:, 3] = 1 + trace
    diagonal = np.stack([d0, d1, d2, trace], axis=1)
    choice = diagonal.argmax(axis=1)  # the first of equals, as scipy
    for i in np.unique(choice).tolist():
        if i < 3:
            sel = choice == i
            j, k = (i + 1) % 3, (i + 2) % 3
            a = m[sel]
            qi = np.empty((len(a), 4))
            qi[:, i] = 1 - trace[sel] + 2 * a[:, i, i]
            qi[:, j] = a[:, j, i] + a[:, i, j]
            qi[:, k] = a[:, k, i] + a[:, i, k]
            qi[:, 3] = a[:, k, j] - a[:, j, k]
            q[sel] = qi
    q0, q1, q2, q3 = q[:, 0], q[:, 1], q[:, 2], q[:, 3]
    q /= np.sqrt(q0 * q0 + q1 * q1 + q2 * q2 + q3 * q3)[:, None]
    return q[0] if one else q


def _rotvec(q: np.ndarray, atan2) -> np.ndarray:
    """Rotation vectors (N,3) of unit quaternions (N,4): scipy's ``as_rotvec`` (the canonical sign, w >= 0)."""
    q0, q1, q2, q3 = q[:, 0], q[:, 1], q[:, 2], q[:, 3]
    flip = (q3 < 0) | ((q3 == 0) & ((q0 < 0) | ((q0 == 0) & ((q1 < 0) | ((q1 == 0) & (q2 < 0))))))
    xyz = np.where(flip[:, None], -q[:, :3], q[:, :3])
    w = np.where(flip, -q3, q3)
    x, y, z = xyz[:, 0], xyz[:, 1], xyz[:, 2]
    angle = 2 * atan2(np.sqrt(x * x + y * y + z * z), w)
    with np.errstate(invalid="ignore", divide="ignore"):
        scale = angle / np.sin(angle / 2)
    small = angle <= _SERIES_RAD
    if small.any():
        a2 = angle[small] * angle[small]
        scale[small] = 2 + a2 / 12 + 7 * a2 * a2 / 2880
    return scale[:, None] * xyz


def rot_to_quat_xyzw(R: np.ndarray) -> np.ndarray:
    """Quaternion(s) xyzw of rotation matrix(es), with w >= 0 (scipy's ``from_matrix``, as ``_quaternions``)."""
    q = _quaternions(R)
    return np.where(q[..., 3:4] < 0.0, -q, q)


__all__ = ["quat_xyzw_to_rot", "rot_to_quat_xyzw", "so3_exp", "so3_log", "so3_log_batch"]
