"""The hot loop of the 3D filter without numpy's per-call overhead: the strapdown prediction, error
injection and the Kalman update on Python floats and a handful of numpy calls on preallocated arrays.

A numpy call costs about 1 us whatever its size, so a 3-vector or 3x3 step is cheaper on Python floats,
while the 15x15 covariance products stay in numpy. The filter's nominal state is a Python list of 33 floats
(the layout of ``state3d``): the kernels read and write it without a conversion. Same mathematics as
``state3d.ins_step``, ``state3d.boxplus``, ``measure3d`` and ``kalman.kalman_update`` (the tests compare
them): the results differ from those only by floating-point rounding. ``P`` is updated in place (one buffer
for the whole run).
"""

from __future__ import annotations

import math
import operator

import numpy as np

from ...geometry import so3_exp_scalars, so3_log_scalars
from .state3d import Layout


class InsPredictor:
    """``state3d.ins_step`` writing only the non-constant blocks of a preallocated F. ``F`` is returned and
    overwritten by the next call."""

    def __init__(self, L: Layout, g: np.ndarray):
        self.F = L.eye.copy()
        self._flat = self.F.reshape(-1)
        n = L.n
        idx = [r * n + c for r in range(3) for c in range(3)]  # dR^T
        for r0, c0 in ((3, 0), (3, 12), (6, 0), (6, 12)):  # h Rf, h R, -dt Rf, -dt R
            idx += [(r0 + r) * n + c0 + c for r in range(3) for c in range(3)]
        idx += [0 * n + 9, 1 * n + 10, 2 * n + 11, 3 * n + 6, 4 * n + 7, 5 * n + 8]
        self._idx = np.array(idx)
        self.gx, self.gy, self.gz = (float(v) for v in g)

    def propagate(self, x: list[float], P: np.ndarray, P_diag: np.ndarray, rate: np.ndarray, dt: float,
                  w: list[float], f: list[float]) -> np.ndarray:
        """One step of ``x`` (as ``__call__``) and of ``P`` in place: ``F P F^T`` plus the process noise
        ``rate * dt`` on its diagonal ``P_diag`` (a view of P). Returns F."""
        F = self(x, dt, w, f)
        F.dot(P).dot(F.T, out=P)
        P_diag += rate * dt
        return F

    def __call__(self, x: list[float], dt: float, w: tuple[float, float, float], f: tuple[float, float, float]
                 ) -> np.ndarray:
        """One step of the state ``x`` (a list, in place) with base-frame rate ``w`` and specific force ``f``
        (raw: biases included)."""
        (r0, r1, r2, r3, r4, r5, r6, r7, r8, px, py, pz, vx, vy, vz, bx, by, bz, ax, ay, az) = x[:21]
        d0, d1, d2, d3, d4, d5, d6, d7, d8 = so3_exp_scalars((w[0] - bx) * dt, (w[1] - by) * dt, (w[2] - bz) * dt)
        fx, fy, fz = f[0] - ax, f[1] - ay, f[2] - az
        sx, sy, sz = r0 * fx + r1 * fy + r2 * fz, r3 * fx + r4 * fy + r5 * fz, r6 * fx + r7 * fy + r8 * fz
        gx, gy, gz = sx + self.gx, sy + self.gy, sz + self.gz
        hd = 0.5 * dt
        # Rf = [R fc]x R
        f0, f1, f2 = -sz * r3 + sy * r6, -sz * r4 + sy * r7, -sz * r5 + sy * r8
        f3, f4, f5 = sz * r0 - sx * r6, sz * r1 - sx * r7, sz * r2 - sx * r8
        f6, f7, f8 = -sy * r0 + sx * r3, -sy * r1 + sx * r4, -sy * r2 + sx * r5
        h, m = -0.5 * dt * dt, -dt
        self._flat[self._idx] = [  # a list: numpy takes it faster than a tuple
            d0, d3, d6, d1, d4, d7, d2, d5, d8,
            h * f0, h * f1, h * f2, h * f3, h * f4, h * f5, h * f6, h * f7, h * f8,
            h * r0, h * r1, h * r2, h * r3, h * r4, h * r5, h * r6, h * r7, h * r8,
            m * f0, m * f1, m * f2, m * f3, m * f4, m * f5, m * f6, m * f7, m * f8,
            m * r0, m * r1, m * r2, m * r3, m * r4, m * r5, m * r6, m * r7, m * r8,
            m, m, m, dt, dt, dt]
        x[:15] = mul3((r0, r1, r2, r3, r4, r5, r6, r7, r8), (d0, d1, d2, d3, d4, d5, d6, d7, d8)) + (
            px + (vx + hd * gx) * dt, py + (vy + hd * gy) * dt, pz + (vz + hd * gz) * dt,
            vx + gx * dt, vy + gy * dt, vz + gz * dt)
        return self.F


def interval_midpoints(stamps_ns: np.ndarray, w: np.ndarray, f: np.ndarray
                       ) -> tuple[list[list[float]], list[list[float]]]:
    """Rate and specific force at the midpoint of each IMU interval [t_i, t_i+1], linearly interpolated by the
    same float operations as ``Ekf3d._imu_at`` (numpy does them elementwise in the same order: equal
    bits), once for the whole series instead of once per filter step."""
    st = np.asarray(stamps_ns, np.int64)
    if len(st) < 2:
        return [], []
    a = ((0.5 * (st[:-1] + st[1:]) - st[:-1]) / (st[1:] - st[:-1]))[:, None]
    return (w[:-1] + a * (w[1:] - w[:-1])).tolist(), (f[:-1] + a * (f[1:] - f[:-1])).tolist()


def mul3(a, b) -> tuple[float, ...]:
    """The product of two 3x3 matrices given row-major as 9 floats each, row-major."""
    a0, a1, a2, a3, a4, a5, a6, a7, a8 = a
    b0, b1, b2, b3, b4, b5, b6, b7, b8 = b
    return (a0 * b0 + a1 * b3 + a2 * b6, a0 * b1 + a1 * b4 + a2 * b7, a0 * b2 + a1 * b5 + a2 * b8,
            a3 * b0 + a4 * b3 + a5 * b6, a3 * b1 + a4 * b4 + a5 * b7, a3 * b2 + a4 * b5 + a5 * b8,
            a6 * b0 + a7 * b3 + a8 * b6, a6 * b1 + a7 * b4 + a8 * b7, a6 * b2 + a7 * b5 + a8 * b8)


def body_velocity(x: list[float], z: list[float], comps: tuple[int, ...], H: np.ndarray) -> list[float]:
    """``measure3d.body_velocity`` on floats: the residuals ``z - (R^T v)[comps]``; ``H`` (len(comps), n, zero
    beyond its two blocks) gets the rows on dtheta ([vb]x) and dv (R^T)."""
    r0, r1, r2, r3, r4, r5, r6, r7, r8, _, _, _, vx, vy, vz = x[:15]
    b0, b1, b2 = r0 * vx + r3 * vy + r6 * vz, r1 * vx + r4 * vy + r7 * vz, r2 * vx + r5 * vy + r8 * vz
    if comps == (0, 1, 2):  # every component in order (the usual twist): H's first 9 columns by flat index
        H.reshape(-1)[_velocity_block_index(H.shape[1])] = [0.0, -b2, b1, 0.0, 0.0, 0.0, r0, r3, r6,
                                                            b2, 0.0, -b0, 0.0, 0.0, 0.0, r1, r4, r7,
                                                            -b1, b0, 0.0, 0.0, 0.0, 0.0, r2, r5, r8]
        return [z[0] - b0, z[1] - b1, z[2] - b2]
    rows = ((0.0, -b2, b1, 0.0, 0.0, 0.0, r0, r3, r6), (b2, 0.0, -b0, 0.0, 0.0, 0.0, r1, r4, r7),
            (-b1, b0, 0.0, 0.0, 0.0, 0.0, r2, r5, r8))  # [vb]x and R^T, dp between them untouched
    H[:, 0:9] = [rows[c] for c in comps]
    vb = (b0, b1, b2)
    return [z[k] - vb[c] for k, c in enumerate(comps)]


_VELOCITY_BLOCK_INDEX: dict[int, np.ndarray] = {}


def _velocity_block_index(n: int) -> np.ndarray:
    """Flat indexes of the first 9 columns of a (3, n) H, row by row (a flat list goes in faster than rows)."""
    idx = _VELOCITY_BLOCK_INDEX.get(n)
    if idx is None:
        idx = _VELOCITY_BLOCK_INDEX[n] = np.array([k * n + c for k in range(3) for c in range(9)])
    return idx


def wheel_velocity_rows(vel: np.ndarray, var: np.ndarray, use: set[str], nonholonomic_sigma: float,
                        nonholonomic_rel: float = 0.0) -> list[tuple[tuple[int, ...], list[float], list[float]] | None]:
    """Per wheel message, the base-velocity components it measures (``comps``, values ``z``, variances), or
    None: with ``velocity`` each finite component as measured; with ``speed`` the forward speed and zero
    lateral and vertical speed (the non-holonomic constraint, sigma ``hypot(nonholonomic_sigma, nonholonomic_rel
    x forward speed)``) for components ``velocity`` did not give. Worked out once for the whole series (the usual
    all-finite messages by numpy), not per filter step."""
    vel_l, var_l = vel.tolist(), var.tolist()
    fin = np.isfinite(vel)
    full = fin.all(axis=1).tolist()
    nh_l = (nonholonomic_sigma**2 + (nonholonomic_rel * np.nan_to_num(vel[:, 0]))**2).tolist()
    rows: list = []
    for v, vv, ok, nh in zip(vel_l, var_l, full, nh_l):
        if ok and "velocity" in use:
            rows.append(((0, 1, 2), v, vv))
        elif ok and "speed" in use:
            rows.append(((0, 1, 2), [v[0], 0.0, 0.0], [vv[0], nh, nh]))
        else:
            rows.append(_wheel_row(v, vv, use, nh))
    return rows


def _wheel_row(vel: list[float], vvar: list[float], use: set[str], nonholonomic_var: float):
    comps, z, var = [], [], []
    if "velocity" in use:
        for c in range(3):
            if math.isfinite(vel[c]):
                comps.append(c), z.append(vel[c]), var.append(vvar[c])
    if "speed" in use and math.isfinite(vel[0]):
        for c in range(3):
            if c not in comps:
                comps.append(c)
                z.append(vel[0] if c == 0 else 0.0)
                var.append(vvar[0] if c == 0 else nonholonomic_var)
    return (tuple(comps), z, var) if comps else None


def orientation(x: list[float], R_meas: list[float], cov_world: np.ndarray, isotropic: bool = False
                ) -> tuple[tuple[float, ...], np.ndarray]:
    """``measure3d.orientation`` without its H (a selection of dtheta): (residual ``log(R^T R_meas)``, noise
    ``R^T cov_world R``); ``R_meas`` row-major as 9 floats. ``isotropic``: ``cov_world`` is ``c I``, which
    every rotation leaves as it is (``isotropic_variances``)."""
    r0, r1, r2, r3, r4, r5, r6, r7, r8 = x[:9]
    r = so3_log_scalars(mul3((r0, r3, r6, r1, r4, r7, r2, r5, r8), R_meas))
    if isotropic:
        return r, cov_world
    Rt = np.array(x[:9]).reshape(3, 3).T
    return r, Rt.dot(cov_world).dot(Rt.T)


def isotropic_variances(cov: np.ndarray) -> list[float | None]:
    """Per 3x3 covariance of ``cov`` (N,3,3): ``c`` where it is exactly ``c I`` (the usual IMU driver's
    orientation covariance), else None."""
    c = np.asarray(cov)[:, 0, 0]
    iso = (cov == c[:, None, None] * np.eye(3)).all(axis=(1, 2))
    return [v if ok else None for v, ok in zip(c.tolist(), iso.tolist())]


def inject(x: list[float], dx: np.ndarray, L: Layout) -> None:
    """``state3d.boxplus`` on the state as a list: inject an error-state correction into ``x`` in place."""
    injector(L)(x, dx)


def injector(L: Layout):
    """``inject`` for one layout, as a function of (state list, correction array) that the filter calls per
    update (no keyword binding to unpack per call)."""
    core, end = L.core, 6 + L.core  # x[9:end] (p, v, b (, ba)) += d[3:core]
    exp, add = so3_exp_scalars, operator.add

    def apply(x: list[float], dx: np.ndarray) -> None:
        d = dx.tolist()
        x[:end] = mul3(x[:9], exp(d[0], d[1], d[2])) + tuple(map(add, x[9:end], d[3:core]))
        if L.clone:
            x[21:33] = mul3(x[21:30], exp(d[core], d[core + 1], d[core + 2])) + tuple(
                map(add, x[30:33], d[core + 3:core + 6]))

    return apply


def boxplus(x: np.ndarray, dx: np.ndarray, L: Layout) -> None:
    """``inject`` on a state array (the smoother's), in place."""
    s = x.tolist()
    inject(s, dx, L)
    x[:] = s
