"""Platform motion as exact analytic functions of time.

A trajectory is built from smooth pieces whose first and second derivatives are known in closed form:
a cubic spline path through waypoints (C2), a progress law along it (rest, quintic smooth-step ramp,
cruise), sums of sinusoids (sway, bobbing, sweeps) and smooth-step envelopes. From them
:class:`Trajectory` gives, at any times, the base pose, its world velocity and acceleration, and its
angular velocity and acceleration in the base frame, all exact (no finite differences), so synthesised
IMU data integrates back to the ground truth.

Times ``t_s`` are float seconds since the trajectory start (short relative durations, as DESIGN.md allows).
Orientation is yaw-pitch-roll, ``R_world_base = Rz(yaw) @ Ry(pitch) @ Rx(roll)``.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from scipy.interpolate import CubicSpline

from .terrain import Hills

# A scalar signal evaluated at times: (value, first derivative, second derivative), each shaped like t.
Signal3 = tuple[np.ndarray, np.ndarray, np.ndarray]


@dataclass(frozen=True)
class Sines:
    """sum_i amp_i * sin(2 pi freq_i t + phase_i), with exact derivatives."""

    amps: tuple[float, ...] = ()
    freqs_hz: tuple[float, ...] = ()
    phases_rad: tuple[float, ...] = ()

    def __call__(self, t: np.ndarray) -> Signal3:
        t = np.asarray(t, dtype=np.float64)
        f0, f1, f2 = np.zeros_like(t), np.zeros_like(t), np.zeros_like(t)
        for a, f, p in zip(self.amps, self.freqs_hz, self.phases_rad):
            w = 2.0 * np.pi * f
            s, c = np.sin(w * t + p), np.cos(w * t + p)
            f0 += a * s
            f1 += a * w * c
            f2 -= a * w * w * s
        return f0, f1, f2


def smoothstep(t: np.ndarray, t0_s: float, width_s: float) -> Signal3:
    """0 before ``t0_s``, 1 after ``t0_s + width_s``, quintic (C2) in between."""
    x = np.clip((np.asarray(t, dtype=np.float64) - t0_s) / width_s, 0.0, 1.0)
    inside = (x > 0.0) & (x < 1.0)
    v = x**3 * (10.0 - 15.0 * x + 6.0 * x * x)
    d1 = np.where(inside, 30.0 * x * x * (1.0 - x) ** 2 / width_s, 0.0)
    d2 = np.where(inside, 60.0 * x * (1.0 - x) * (1.0 - 2.0 * x) / width_s**2, 0.0)
    return v, d1, d2


def smoothstep_integral(t: np.ndarray, t0_s: float, width_s: float) -> np.ndarray:
    """Integral from -inf to t of :func:`smoothstep` (seconds)."""
    tt = np.asarray(t, dtype=np.float64)
    x = np.clip((tt - t0_s) / width_s, 0.0, 1.0)
    ramp = width_s * (x**6 - 3.0 * x**5 + 2.5 * x**4)
    return np.where(tt > t0_s + width_s, 0.5 * width_s + (tt - t0_s - width_s), ramp)


def product(a: Signal3, b: Signal3) -> Signal3:
    return a[0] * b[0], a[1] * b[0] + a[0] * b[1], a[2] * b[0] + 2.0 * a[1] * b[1] + a[0] * b[2]


def add(*signals: Signal3) -> Signal3:
    return tuple(sum(s[i] for s in signals) for i in range(3))  # type: ignore[return-value]


@dataclass
class Path2D:
    """A C2 cubic spline through x-y waypoints, parameterised by cumulative chord length (about metres).

    ``closed`` paths repeat (the first waypoint is appended at the end); open ones extrapolate.
    """

    waypoints_xy: np.ndarray
    closed: bool = True
    _sx: CubicSpline = field(init=False, repr=False)
    _sy: CubicSpline = field(init=False, repr=False)
    length_m: float = field(init=False)

    def __post_init__(self) -> None:
        pts = np.asarray(self.waypoints_xy, dtype=np.float64)
        if self.closed:
            pts = np.vstack([pts, pts[:1]])
        knots = np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(pts, axis=0), axis=1))])
        bc = "periodic" if self.closed else "not-a-knot"
        self._sx = CubicSpline(knots, pts[:, 0], bc_type=bc)
        self._sy = CubicSpline(knots, pts[:, 1], bc_type=bc)
        self.length_m = float(knots[-1])

    def derivs(self, s: np.ndarray, order: int) -> np.ndarray:
        """d^order/ds^order of (x, y) at arc parameters ``s`` -> (N,2)."""
        s = np.asarray(s, dtype=np.float64)
        if self.closed:
            s = np.mod(s, self.length_m)
        return np.stack([self._sx(s, order), self._sy(s, order)], axis=-1)


@dataclass
class Progress:
    """Distance along the path: rest until ``t_rest_s``, a smooth-step speed ramp over ``ramp_s`` to
    ``speed_mps``, then cruise with a smooth distance wobble ``wobble`` (metres, faded in after the ramp)."""

    speed_mps: float
    t_rest_s: float = 1.5
    ramp_s: float = 1.5
    wobble: Sines = field(default_factory=Sines)
    s0_m: float = 0.0

    def __call__(self, t: np.ndarray) -> Signal3:
        t = np.asarray(t, dtype=np.float64)
        env = smoothstep(t, self.t_rest_s, self.ramp_s)
        base = (self.s0_m + self.speed_mps * smoothstep_integral(t, self.t_rest_s, self.ramp_s),
                self.speed_mps * env[0], self.speed_mps * env[1])
        late = smoothstep(t, self.t_rest_s + self.ramp_s, 2.0 * self.ramp_s)
        return add(base, product(late, self.wobble(t)))


@dataclass
class MotionState:
    """Exact kinematics of the base at N instants (world frame unless noted)."""

    t_s: np.ndarray  # (N,)
    position_m: np.ndarray  # (N,3)
    velocity_mps: np.ndarray  # (N,3)
    accel_mps2: np.ndarray  # (N,3)
    R_world_base: np.ndarray  # (N,3,3)
    omega_base_radps: np.ndarray  # (N,3) angular velocity in the base frame
    alpha_base_radps2: np.ndarray  # (N,3) angular acceleration in the base frame

    @property
    def poses(self) -> np.ndarray:
        """T_world_base (N,4,4)."""
        T = np.zeros((len(self.t_s), 4, 4))
        T[:, :3, :3] = self.R_world_base
        T[:, :3, 3] = self.position_m
        T[:, 3, 3] = 1.0
        return T


def ypr_to_matrix(yaw: np.ndarray, pitch: np.ndarray, roll: np.ndarray) -> np.ndarray:
    """Rz(yaw) @ Ry(pitch) @ Rx(roll), vectorised -> (N,3,3)."""
    cy, sy, cp, sp, cr, sr = np.cos(yaw), np.sin(yaw), np.cos(pitch), np.sin(pitch), np.cos(roll), np.sin(roll)
    R = np.empty(np.shape(yaw) + (3, 3))
    R[..., 0, 0] = cy * cp
    R[..., 0, 1] = cy * sp * sr - sy * cr
    R[..., 0, 2] = cy * sp * cr + sy * sr
    R[..., 1, 0] = sy * cp
    R[..., 1, 1] = sy * sp * sr + cy * cr
    R[..., 1, 2] = sy * sp * cr - cy * sr
    R[..., 2, 0] = -sp
    R[..., 2, 1] = cp * sr
    R[..., 2, 2] = cp * cr
    return R


def ypr_rates_to_body(ypr: tuple[Signal3, Signal3, Signal3]) -> tuple[np.ndarray, np.ndarray]:
    """Body angular velocity and acceleration (N,3) from yaw/pitch/roll signals with their derivatives."""
    (_, yd, ydd), (p, pd, pdd), (r, rd, rdd) = ypr
    sp, cp, sr, cr = np.sin(p), np.cos(p), np.sin(r), np.cos(r)
    wx = rd - yd * sp
    wy = pd * cr + yd * cp * sr
    wz = -pd * sr + yd * cp * cr
    ax = rdd - ydd * sp - yd * pd * cp
    ay = pdd * cr - pd * rd * sr + ydd * cp * sr - yd * pd * sp * sr + yd * rd * cp * cr
    az = -pdd * sr - pd * rd * cr + ydd * cp * cr - yd * pd * sp * cr - yd * rd * cp * sr
    return np.stack([wx, wy, wz], axis=-1), np.stack([ax, ay, az], axis=-1)


@dataclass
class Trajectory:
    """Base motion: x-y along ``path`` by ``progress``; height, yaw offset, pitch and roll as signals.

    ``heading_follows_path``: yaw = path tangent heading + ``yaw_offset`` (wheeled platforms keep
    ``yaw_offset`` zero so they never move sideways). ``terrain``: hills along the path (see :mod:`.terrain`),
    their height added to the base's and their grade to its pitch; None: flat ground.
    """

    path: Path2D
    progress: Progress
    z0_m: float = 0.0
    z_wobble: Sines = field(default_factory=Sines)
    yaw_offset: Sines = field(default_factory=Sines)
    pitch: Sines = field(default_factory=Sines)
    roll: Sines = field(default_factory=Sines)
    fade_in_s: float = 1.5  # sway signals fade in after the rest period
    t_rest_s: float = 1.5
    terrain: Hills | None = None

    def _envelope(self, t: np.ndarray) -> Signal3:
        return smoothstep(t, self.t_rest_s, self.fade_in_s)

    def _faded(self, sig: Sines, t: np.ndarray) -> Signal3:
        return product(self._envelope(t), sig(t))

    def heading(self, t: np.ndarray) -> Signal3:
        """Path tangent heading and its time derivatives (continuous, unwrapped)."""
        s, sd, sdd = self.progress(t)
        d1, d2, d3 = (self.path.derivs(s, k) for k in (1, 2, 3))
        x1, y1, x2, y2, x3, y3 = d1[..., 0], d1[..., 1], d2[..., 0], d2[..., 1], d3[..., 0], d3[..., 1]
        D = x1 * x1 + y1 * y1
        N = x1 * y2 - y1 * x2
        h_s = N / D
        h_ss = ((x1 * y3 - y1 * x3) * D - N * 2.0 * (x1 * x2 + y1 * y2)) / (D * D)
        h = np.arctan2(y1, x1)  # only cos/sin of yaw are used, so wrapping is harmless
        return h, h_s * sd, h_ss * sd * sd + h_s * sdd

    def state(self, t_s: np.ndarray) -> MotionState:
        t = np.atleast_1d(np.asarray(t_s, dtype=np.float64))
        s, sd, sdd = self.progress(t)
        d1, d2 = self.path.derivs(s, 1), self.path.derivs(s, 2)
        z = add((np.full_like(t, self.z0_m), np.zeros_like(t), np.zeros_like(t)), self._faded(self.z_wobble, t))
        pitch, roll = self._faded(self.pitch, t), self._faded(self.roll, t)
        if self.terrain is not None:
            lift, grade = self.terrain.along((s, sd, sdd))
            z, pitch = add(z, lift), add(pitch, grade)
        pos = np.column_stack([self.path.derivs(s, 0), z[0]])
        vel = np.column_stack([d1 * sd[:, None], z[1]])
        acc = np.column_stack([d2 * (sd * sd)[:, None] + d1 * sdd[:, None], z[2]])
        yaw = add(self.heading(t), self._faded(self.yaw_offset, t))
        R = ypr_to_matrix(yaw[0], pitch[0], roll[0])
        omega, alpha = ypr_rates_to_body((yaw, pitch, roll))
        return MotionState(t, pos, vel, acc, R, omega, alpha)

    def poses(self, t_s: np.ndarray) -> np.ndarray:
        """T_world_base (N,4,4) at ``t_s``."""
        return self.state(t_s).poses
