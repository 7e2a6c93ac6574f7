"""IMU model: the navigation state and its propagation between two stamps (start-up is in ``startup``).

Measurement model (lecture): gyro ``w_i = R_i_b w_b + b_g + n``, accelerometer
``f_i = R_i_w (a_imu - g) + b_a + n`` with ``g = (0, 0, -9.81)``. The IMU sits at lever arm ``r`` in the
base frame, so ``a_imu = a_base + R_w_b (alpha_b x r + w_b x (w_b x r))``.

The propagated state is the base frame's: rotation ``R_world_base``, position and velocity in world,
biases in the IMU frame, and gravity in world (the world frame is the first scan's, not levelled, so the
filter refines gravity's direction as it does the biases). Covariance of the 18-dim error state
[dtheta, dp, dv, dbg, dba, dg] (rotation error on the right: R = R_hat exp(dtheta)) is propagated alongside
for the EKF.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from ..geometry import cross_rows, so3_exp, so3_exp_one
from ..model.calibration import Extrinsics
from ..model.records import ImuBatch

GRAVITY_MPS2 = 9.81
STATE_DIM = 18  # error state: rotation, position, velocity, gyro bias, accel bias, gravity (3 each)
# An IMU gap: no sample for longer than this (5 periods of a 100 Hz IMU); interpolated rates lose ~alpha T^2 / 8 of rotation.
MAX_IMU_GAP_NS = 50_000_000


def gravity_vector(gravity_mps2: float = GRAVITY_MPS2) -> np.ndarray:
    """Gravity in a z-up world: (0, 0, -g)."""
    return np.array([0.0, 0.0, -gravity_mps2])


@dataclass
class NavState:
    """Base state at ``stamp_ns`` with its error-state covariance ``P`` (18x18)."""

    stamp_ns: int
    R: np.ndarray  # R_world_base
    p: np.ndarray  # base origin in world
    v: np.ndarray  # base velocity in world
    bg: np.ndarray  # gyro bias, IMU frame
    ba: np.ndarray  # accel bias, IMU frame
    P: np.ndarray = field(default_factory=lambda: np.eye(STATE_DIM) * 1e-6)
    g: np.ndarray = field(default_factory=gravity_vector)  # gravity in world

    def pose(self) -> np.ndarray:
        T = np.eye(4)
        T[:3, :3], T[:3, 3] = self.R, self.p
        return T

    def copy(self) -> "NavState":
        return NavState(self.stamp_ns, self.R.copy(), self.p.copy(), self.v.copy(), self.bg.copy(), self.ba.copy(),
                        self.P.copy(), self.g.copy())


@dataclass
class Propagation:
    """Base poses along the propagated interval (for deskew) and the final state."""

    stamps_ns: np.ndarray
    poses: np.ndarray  # (M,4,4) T_world_base
    state: NavState
    gap: bool  # the interval had an IMU gap or no IMU at all


def running_integral(t_s: np.ndarray, x: np.ndarray, skip: np.ndarray | None = None) -> np.ndarray:
    """The trapezoid integral of ``x`` (samples along the first axis, at seconds ``t_s``) from the first sample to
    each; steps where ``skip`` (one per step, e.g. an IMU gap) add nothing."""
    dt = np.diff(t_s) if skip is None else np.where(skip, 0.0, np.diff(t_s))
    steps = 0.5 * (x[1:] + x[:-1]) * dt.reshape(-1, *(1,) * (x.ndim - 1))
    return np.concatenate([np.zeros((1, *x.shape[1:])), np.cumsum(steps, axis=0)])


def interpolate_imu(imu: ImuBatch, t_ns: int) -> tuple[np.ndarray, np.ndarray]:
    """Gyro and accel at ``t_ns`` by linear interpolation (held at the ends)."""
    st = imu.stamps_ns
    i = int(np.searchsorted(st, t_ns))
    if i <= 0:
        return imu.gyro_radps[0], imu.accel_mps2[0]
    if i >= len(st):
        return imu.gyro_radps[-1], imu.accel_mps2[-1]
    a = (t_ns - st[i - 1]) / (st[i] - st[i - 1])
    return ((1 - a) * imu.gyro_radps[i - 1] + a * imu.gyro_radps[i],
            (1 - a) * imu.accel_mps2[i - 1] + a * imu.accel_mps2[i])


def imu_gap_ns(stamps_ns: np.ndarray, t0_ns: int, t1_ns: int) -> tuple[int, int]:
    """(cost, length) of the worst stretch without IMU samples that a propagation over [t0, t1] crosses.

    Across a stretch the rates are interpolated between its samples (held beyond the last): the rotation lost is
    about the angular acceleration times the integral, over the part of the stretch inside [t0, t1], of the time to
    the nearest sample. ``cost`` is the length of a stretch lying wholly inside that loses as much (its integral is
    T^2 / 4): a stretch's own length when it is inside the interval, less at an edge of a long one (sqrt(2) x the
    part inside), more for an interval deep within a long one. ``length``: that stretch's length, clipped to the
    interval on a side without samples. No sample at all costs the whole interval.
    """
    s = np.asarray(stamps_ns, dtype=np.int64)
    i = int(np.searchsorted(s, t0_ns, side="right"))  # s[:i] <= t0
    j = int(np.searchsorted(s, t1_ns, side="left"))  # s[j:] >= t1
    span = int(t1_ns - t0_ns)
    if i == j and (i == 0 or j == len(s)):  # no sample in the interval nor on one side of it
        return span, span
    ends = (s[max(i - 1, 0):j + 1] - t0_ns).astype(np.float64)  # the samples around and in it, from t0
    ends = np.concatenate([[-np.inf] if i == 0 else [], ends, [np.inf] if j == len(s) else []])
    a, b = ends[:-1], ends[1:]  # the stretches between consecutive samples
    u, v = np.maximum(a, 0.0), np.minimum(b, float(span))  # each one's part inside the interval
    keep = v > u
    a, b, u, v = a[keep], b[keep], u[keep], v[keep]
    if not len(a):
        return 0, 0
    half = np.where(np.isfinite(a) & np.isfinite(b), (b - a) ** 2 / 4.0, 0.0)

    def area(t):  # integral of the time to the nearest sample, min(t - a, b - t), from a (or from b's side)
        to_a, to_b = t - a, b - t
        return np.where(to_a <= to_b, to_a**2 / 2.0, half - to_b**2 / 2.0)

    cost = 2.0 * np.sqrt(np.maximum(area(v) - area(u), 0.0))
    k = int(np.argmax(cost))
    length = min(b[k], span) - max(a[k], 0.0) if np.isinf(a[k]) or np.isinf(b[k]) else b[k] - a[k]
    return int(cost[k]), int(length)


def imu_gap_free(stamps_ns: np.ndarray, t0_ns: int, t1_ns: int, max_gap_ns: int = MAX_IMU_GAP_NS) -> bool:
    """True when ``imu_gap_ns`` over [t0, t1] cannot cost more than ``max_gap_ns``: a sample at or before t0, one at
    or after t1, and no two consecutive ones between further apart than half of it (a stretch costs at most its
    length). The usual case in a few operations; False says only that ``imu_gap_ns`` must tell."""
    s = stamps_ns
    i = int(np.searchsorted(s, t0_ns, side="right"))
    j = int(np.searchsorted(s, t1_ns, side="left"))
    if i == 0 or j == len(s):
        return False
    around = s[i - 1:j + 1]
    return len(around) < 2 or int((around[1:] - around[:-1]).max()) <= max_gap_ns // 2


def imu_hole_ns(stamps_ns: np.ndarray, t0_ns: int, t1_ns: int, max_gap_ns: int = MAX_IMU_GAP_NS) -> int | None:
    """The length of the stretch without samples that makes [t0, t1] an IMU gap (``imu_gap_ns``'s cost over
    ``max_gap_ns``), None where there is none (``imu_gap_free`` answers the usual case first)."""
    if imu_gap_free(stamps_ns, t0_ns, t1_ns, max_gap_ns):
        return None
    cost_ns, hole_ns = imu_gap_ns(stamps_ns, t0_ns, t1_ns)
    return hole_ns if cost_ns > max_gap_ns else None


def propagate(state: NavState, imu: ImuBatch, t_end_ns: int, ext: Extrinsics, *,
              g_world: np.ndarray | None = None, noise=None, max_gap_ns: int = MAX_IMU_GAP_NS,
              planar: bool = False, accel: bool = True) -> Propagation:
    """Integrate the IMU from ``state.stamp_ns`` to ``t_end_ns`` (midpoint rule, lever arm included).

    ``g_world``: gravity in the state's world frame (default: the state's own ``g``). ``accel=False`` integrates
    the gyro only and keeps the velocity constant (the motion prior while gravity is not yet known).
    ``imu`` should hold samples spanning the interval; where it does not (a gap, or no data), the last
    angular rate is held and acceleration taken as zero, and ``gap`` is set.
    """
    t0 = state.stamp_ns
    g = state.g if g_world is None else np.asarray(g_world, dtype=np.float64)
    R_bi, r = ext.R_base_imu, ext.lever_m
    s = state.copy()
    if len(imu) == 0:
        return _hold(s, t_end_ns)
    times, dts, Rs, gap, inside, w_b, ends = _rotations(s.R, s.bg, imu, t0, t_end_ns, R_bi, max_gap_ns)
    accs = np.vstack([ends[0][1], imu.accel_mps2[inside], ends[1][1]])
    f_b = (accs - s.ba) @ R_bi.T  # specific force at the IMU, base axes
    n = len(times)
    # acceleration of the base origin in world at every sample (lever arm removed), then trapezoids
    safe_dt = np.where(dts > 0, dts, 1.0)
    alpha = np.vstack([(w_b[1:] - w_b[:-1]) / safe_dt[:, None], np.zeros((1, 3))])
    alpha[-1] = alpha[-2] if n > 2 else 0.0
    if accel:
        lever = cross_rows(alpha, r) + cross_rows(w_b, cross_rows(w_b, r))
        a_w = np.einsum("nij,nj->ni", Rs, f_b - lever) + g
    else:
        a_w = np.zeros((n, 3))
    a_mid = 0.5 * (a_w[1:] + a_w[:-1])
    dv = a_mid * dts[:, None]
    v = s.v + np.vstack([np.zeros((1, 3)), np.cumsum(dv, axis=0)])
    dp = v[:-1] * dts[:, None] + 0.5 * a_mid * (dts**2)[:, None]
    p = s.p + np.vstack([np.zeros((1, 3)), np.cumsum(dp, axis=0)])
    if noise is not None:
        s.P = _propagate_cov_interval(s.P, Rs, R_bi, w_b, f_b, dts, _noise_matrix(noise))
    s.R, s.p, s.v = Rs[-1], p[-1], v[-1]
    if planar:
        flatten_planar(s)
        Rs, p = _flatten_many(Rs, p)
    poses = np.zeros((n, 4, 4))
    poses[:, :3, :3], poses[:, :3, 3], poses[:, 3, 3] = Rs, p, 1.0
    s.stamp_ns = int(t_end_ns)
    return Propagation(times, poses, s, gap)


def gyro_rotations(R0: np.ndarray, gyro_bias: np.ndarray, imu: ImuBatch, t0_ns: int, t_end_ns: int, ext: Extrinsics,
                   max_gap_ns: int = MAX_IMU_GAP_NS) -> tuple[np.ndarray, np.ndarray, bool]:
    """(stamps, R_world_base (M,3,3) at them, gap): the rotations ``propagate`` integrates from ``R0`` at
    ``t0_ns``, to the bit, without its translation, velocity and covariance (``propagate(..., accel=False)``'s
    poses' rotations, for a sweep's de-skew). No IMU sample at all is a gap with no rotation."""
    if len(imu) == 0:
        return np.array([t0_ns, t_end_ns], dtype=np.int64), np.stack([R0, R0]), True
    times, _, Rs, gap, _, _, _ = _rotations(np.asarray(R0, dtype=np.float64),
                                            np.asarray(gyro_bias, dtype=np.float64), imu, t0_ns, t_end_ns,
                                            ext.R_base_imu, max_gap_ns)
    return times, Rs, gap


def _rotations(R0: np.ndarray, bg: np.ndarray, imu: ImuBatch, t0: int, t_end_ns: int, R_bi: np.ndarray,
               max_gap_ns: int):
    """(times, their intervals in s, rotations at them, gap, the IMU samples inside, base angular rates, the
    interpolated (gyro, accel) at t0 and at the end) of a propagation."""
    inside = (imu.stamps_ns > t0) & (imu.stamps_ns < t_end_ns)
    times = np.concatenate([[t0], imu.stamps_ns[inside], [t_end_ns]])
    ends = interpolate_imu(imu, t0), interpolate_imu(imu, t_end_ns)
    gyros = np.vstack([ends[0][0], imu.gyro_radps[inside], ends[1][0]])
    gap = bool(np.diff(times).max(initial=0) > max_gap_ns) or imu.stamps_ns[-1] < t_end_ns - max_gap_ns \
        or imu.stamps_ns[0] > t0 + max_gap_ns
    w_b = (gyros - bg) @ R_bi.T  # base angular rate at each time
    n = len(times)
    dts = np.diff(times) * 1e-9
    # orientation: midpoint rule, a chain of small rotations
    w_mid = 0.5 * (w_b[1:] + w_b[:-1])
    steps = so3_exp(w_mid * dts[:, None])
    Rs = np.empty((n, 3, 3))
    Rs[0] = R0
    for k in range(n - 1):
        Rs[k + 1] = Rs[k] @ steps[k]
    return times, dts, Rs, gap, inside, w_b, ends


def _flatten_many(Rs: np.ndarray, p: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    yaw = np.arctan2(Rs[:, 1, 0], Rs[:, 0, 0])
    c, si = np.cos(yaw), np.sin(yaw)
    out = np.zeros_like(Rs)
    out[:, 0, 0], out[:, 0, 1], out[:, 1, 0], out[:, 1, 1], out[:, 2, 2] = c, -si, si, c, 1.0
    p = p.copy()
    p[:, 2] = 0.0
    return out, p


def _hold(s: NavState, t_end_ns: int) -> Propagation:
    """No IMU: constant velocity, no rotation."""
    dt = (t_end_ns - s.stamp_ns) * 1e-9
    start = s.pose()
    s.p = s.p + s.v * dt
    s.stamp_ns = int(t_end_ns)
    s.P = s.P + np.diag([1e-4] * 3 + [1e-3] * 3 + [1e-2] * 3 + [0.0] * 9) * max(dt, 0.0)
    return Propagation(np.array([t_end_ns - int(dt * 1e9), t_end_ns], dtype=np.int64), np.stack([start, s.pose()]), s, True)


def flatten_planar(s: NavState) -> None:
    """Keep a planar state in SE(2): no roll, pitch, z or vertical speed."""
    yaw = np.arctan2(s.R[1, 0], s.R[0, 0])
    c, si = np.cos(yaw), np.sin(yaw)
    s.R = np.array([[c, -si, 0.0], [si, c, 0.0], [0.0, 0.0, 1.0]])
    s.p[2] = 0.0
    s.v[2] = 0.0


def _noise_matrix(noise) -> np.ndarray | None:
    if noise is None:
        return None
    return np.array([noise.gyro_noise_radps, noise.accel_noise_mps2, noise.gyro_bias_walk, noise.accel_bias_walk]) ** 2


def _propagate_cov_interval(P: np.ndarray, Rs: np.ndarray, R_bi: np.ndarray, w_b: np.ndarray, f_b: np.ndarray,
                            dts: np.ndarray, q: np.ndarray, substep_s: float = 0.025) -> np.ndarray:
    """Error-state covariance over the interval in sub-steps of about ``substep_s`` (mean rates per sub-step)."""
    total = float(dts.sum())
    if total <= 0:
        return P
    m = max(1, int(round(total / substep_s)))
    edges = np.linspace(0, len(dts), m + 1).astype(int).tolist()
    # the same products as filling a fresh F and Q per sub-step; the constant parts made once
    F = np.eye(STATE_DIM)
    q_rate = np.repeat([q[0], 0.0, q[1], q[2], q[3], 0.0], 3)
    Q = np.zeros((STATE_DIM, STATE_DIM))  # np.diag(q_rate * dt): its diagonal rewritten per sub-step
    Q_diag = Q.reshape(-1)[::STATE_DIM + 1]
    R_R_bi = Rs[edges[:-1]] @ R_bi
    for i, (a, b) in enumerate(zip(edges[:-1], edges[1:])):
        if b <= a:
            continue
        dt = float(dts[a:b].sum())
        w = np.add.reduce(w_b[a:b + 1], axis=0) / (b + 1 - a)  # np.mean's sum and division
        f = np.add.reduce(f_b[a:b + 1], axis=0) / (b + 1 - a)
        F[0:3, 0:3] = so3_exp_one(-w * dt)
        F[0:3, 9:12] = -R_bi * dt
        F[3, 6] = F[4, 7] = F[5, 8] = F[6, 15] = F[7, 16] = F[8, 17] = dt  # identity blocks times dt
        f0, f1, f2 = f.tolist()
        F[6:9, 0:3] = -Rs[a] @ np.array([[0.0, -f2, f1], [f2, 0.0, -f0], [-f1, f0, 0.0]]) * dt  # skew(f)
        F[6:9, 12:15] = -R_R_bi[i] * dt
        np.multiply(q_rate, dt, out=Q_diag)
        P = F @ P @ F.T + Q
    return P
