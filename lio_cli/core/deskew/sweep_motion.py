"""The base's motion within one LiDAR sweep, and each point moved into the sensor frame at one instant.

``PoseSpline`` gives ``T_world_base`` at any instant from stamped poses: a cubic through the four nearest
poses (Lagrange, on positions and on rotation vectors relative to the interval's first pose), or SE(3)
interpolation between the two nearest (``cubic=False``). A pose per scan (odometry at 10 Hz) cannot be
interpolated linearly through a fast, accelerating sweep; the cubic follows it. Beyond the ends it
extrapolates at the end segment's velocity for at most ``extrapolate_ns``.

``gyro_sweep_poses`` takes the rotation within the sweep from the gyro instead (exact to its noise and
bias) and the translation from the spline. ``deskew_to_sensor`` applies either to a scan's points.
"""

from __future__ import annotations

import numpy as np

from ...geometry import interpolate_poses, so3_exp, so3_log
from ...model.calibration import Extrinsics
from ...model.records import ImuBatch
from ..imu import gyro_rotations
from ..motion_compensation import deskew

KNOT_STEP_NS = 4_000_000  # poses within a sweep every 4 ms: blending linearly between them is off by < 0.6 mm at 30 m, 3 rad/s
_IDENTITY = np.eye(4)


class PoseSpline:
    """``T_world_base`` at any instant in [first, last] (plus ``extrapolate_ns`` at either end)."""

    def __init__(self, stamps_ns: np.ndarray, poses: np.ndarray, *, cubic: bool = True, extrapolate_ns: int = 0,
                 max_gap_ns: int | None = None) -> None:
        self.stamps_ns = np.asarray(stamps_ns, dtype=np.int64)
        self.poses = np.asarray(poses, dtype=np.float64)
        if len(self.stamps_ns) == 0 or np.any(np.diff(self.stamps_ns) <= 0):
            raise ValueError("a pose spline needs at least one pose at strictly increasing stamps")
        self.cubic = cubic and len(self.stamps_ns) >= 4
        self.extrapolate_ns = int(extrapolate_ns)
        self.max_gap_ns = max_gap_ns

    @property
    def first_ns(self) -> int:
        return int(self.stamps_ns[0])

    @property
    def last_ns(self) -> int:
        return int(self.stamps_ns[-1])

    def uncovered(self, t0_ns: int, t1_ns: int) -> str | None:
        """None when [t0, t1] is covered, else why not (before the start, after the end, across a gap)."""
        if t0_ns < self.first_ns - self.extrapolate_ns:
            return "before the trajectory starts"
        if t1_ns > self.last_ns + self.extrapolate_ns:
            return "after the trajectory ends"
        if self.max_gap_ns is not None and len(self.stamps_ns) > 1:
            lo = max(int(np.searchsorted(self.stamps_ns, t0_ns, side="right")) - 1, 0)
            hi = min(int(np.searchsorted(self.stamps_ns, t1_ns, side="left")), len(self.stamps_ns) - 1)
            if hi > lo and int(np.diff(self.stamps_ns[lo:hi + 1]).max()) > self.max_gap_ns:
                return "in a gap of the trajectory"
        return None

    def at(self, query_ns: np.ndarray) -> np.ndarray:
        """Poses (N,4,4) at ``query_ns``; outside [first, last] by the end segment's velocity."""
        q = np.asarray(query_ns, dtype=np.int64)
        if len(self.stamps_ns) == 1:
            return np.repeat(self.poses[:1], len(q), axis=0)
        j = np.minimum(np.searchsorted(self.stamps_ns, q), len(self.stamps_ns) - 1)
        if np.all(self.stamps_ns[j] == q):  # at the poses themselves (a scan's own stamp): nothing to interpolate
            return self.poses[j].copy()
        if self.cubic:
            out = np.zeros((len(q), 4, 4))
            out[:, :3, :3], out[:, :3, 3] = self._cubic(q, rotations=True)
            out[:, 3, 3] = 1.0
        else:
            out = interpolate_poses(self.stamps_ns, self.poses, q)
        return self._extrapolated(q, out, rotations=True)

    def positions(self, query_ns: np.ndarray) -> np.ndarray:
        """The translations (N,3) of ``at(query_ns)``, without the work of the rotations."""
        q = np.asarray(query_ns, dtype=np.int64)
        if len(self.stamps_ns) == 1:
            return np.repeat(self.poses[:1, :3, 3], len(q), axis=0)
        if self.cubic:
            out = self._cubic(q, rotations=False)[1]
        else:
            out = interpolate_poses(self.stamps_ns, self.poses, q)[:, :3, 3]
        return self._extrapolated(q, out, rotations=False)

    def _extrapolated(self, q: np.ndarray, out: np.ndarray, rotations: bool) -> np.ndarray:
        """``out`` (poses, or positions without ``rotations``) with the queries beyond either end replaced by
        the end segment's constant velocity."""
        n = len(self.stamps_ns)
        for beyond, i in ((q < self.stamps_ns[0], 0), (q > self.stamps_ns[-1], n - 2)):
            if beyond.any():
                t0, t1 = self.stamps_ns[i], self.stamps_ns[i + 1]
                a = (q[beyond] - t0).astype(np.float64) / float(t1 - t0)
                P0, P1 = self.poses[i], self.poses[i + 1]
                p = P0[:3, 3] + a[:, None] * (P1[:3, 3] - P0[:3, 3])
                if rotations:
                    out[beyond, :3, :3] = P0[:3, :3] @ so3_exp(a[:, None] * so3_log(P0[:3, :3].T @ P1[:3, :3]))
                    out[beyond, :3, 3] = p
                else:
                    out[beyond] = p
        return out

    def _cubic(self, q: np.ndarray, rotations: bool) -> tuple[np.ndarray | None, np.ndarray]:
        """(rotations (N,3,3) or None, positions (N,3)) of the Lagrange cubic through the four nearest poses."""
        st, P = self.stamps_ns, self.poses
        n = len(st)
        i = np.clip(np.searchsorted(st, q, side="right") - 1, 0, n - 2)  # the interval holding each query
        uniq, which = np.unique(i, return_inverse=True)  # a sweep's queries fall in a few intervals
        idx = np.clip(uniq - 1, 0, n - 4)[:, None] + np.arange(4)  # four poses around each (shifted in at the ends)
        nodes = (st[idx] - st[uniq][:, None]).astype(np.float64)[which] * 1e-9  # relative to the interval's start
        x = (q - st[i]).astype(np.float64) * 1e-9
        w = np.ones((len(q), 4))
        for k in range(4):
            for m in range(4):
                if m != k:
                    w[:, k] *= (x - nodes[:, m]) / (nodes[:, k] - nodes[:, m])
        positions = np.einsum("qk,qkj->qj", w, P[idx, :3, 3][which])
        if not rotations:
            return None, positions
        R_u = P[uniq, :3, :3]
        rel = np.einsum("uji,ukjl->ukil", R_u, P[idx, :3, :3])  # R_i^T R_k
        phi = so3_log(rel.reshape(-1, 3, 3)).reshape(len(uniq), 4, 3)[which]
        return R_u[which] @ so3_exp(np.einsum("qk,qkj->qj", w, phi)), positions


def sweep_knots(t0_ns: int, t1_ns: int, step_ns: int = KNOT_STEP_NS) -> np.ndarray:
    """Instants from ``t0_ns`` to ``t1_ns`` (both included) at most ``step_ns`` apart."""
    m = max(2, int(np.ceil((t1_ns - t0_ns) / step_ns)) + 1)
    knots = np.unique(np.rint(np.linspace(t0_ns, t1_ns, m)).astype(np.int64))
    knots[0], knots[-1] = t0_ns, t1_ns
    return knots


def gyro_sweep_poses(spline: PoseSpline, imu: ImuBatch, t0_ns: int, t1_ns: int, t_ref_ns: int, ext: Extrinsics,
                     gyro_bias_radps: np.ndarray) -> tuple[np.ndarray, np.ndarray] | None:
    """(knot stamps, T_world_base at them) over [t0, t1]: rotation integrated from the gyro (bias removed, IMU
    mounting applied), anchored to the spline's rotation at ``t_ref_ns``; translation from the spline.
    None when the IMU does not cover the sweep without a gap."""
    knots, R_gyro, gap = gyro_rotations(np.eye(3), gyro_bias_radps, imu, t0_ns, t1_ns, ext)
    if gap:
        return None
    k_ref = int(np.argmin(np.abs(knots - t_ref_ns)))
    R_ref = spline.at(np.array([t_ref_ns]))[0, :3, :3]
    poses = np.zeros((len(knots), 4, 4))
    poses[:, :3, :3] = (R_ref @ R_gyro[k_ref].T) @ R_gyro  # anchored at the reference instant
    poses[:, :3, 3] = spline.positions(knots)
    poses[:, 3, 3] = 1.0
    return knots, poses


def deskew_to_sensor(points_lidar: np.ndarray, stamps_ns: np.ndarray, knots_ns: np.ndarray, knot_poses: np.ndarray,
                     t_ref_ns: int, T_base_lidar: np.ndarray) -> np.ndarray:
    """Points (N,3) in the sensor frame at ``t_ref_ns`` (one of ``knots_ns``):
    ``T_lidar(ref)_lidar(t_j) p_j = (T_base(ref) T_base_lidar)^-1 T_base(t_j) T_base_lidar p_j``.

    ``core.motion_compensation.deskew`` on the LiDAR's own poses (``T_world_base T_base_lidar`` at the knots),
    so its result is already in the sensor frame at the reference knot.
    """
    return deskew(points_lidar, stamps_ns, knots_ns, knot_poses @ T_base_lidar, t_ref_ns, _IDENTITY)
