"""The 3D error-state model: nominal state layout, error injection (boxplus/boxminus) and the three
process models, each returning its error-state transition F and the diagonal of its process noise Q.

Nominal state ``x`` (flat float64, 33): ``R_world_base`` (9, row-major), ``p`` (3, world), ``v`` (3,
world), ``b`` (3), ``ba`` (3), and a clone of an earlier pose ``Rc`` (9), ``pc`` (3) for relative
odometry. Error state (rotation errors on the right, ``R = R_hat exp(dtheta)``, in the base frame):
``[dtheta, dp, dv, db (, dba)] (+ [dtheta_c, dp_c])``.

Models (lecture: predict from the IMU, or from a motion model when there is none):
- ``ins``: gyro and accelerometer drive the prediction; ``b`` is the gyro bias, ``ba`` the accel bias
  (both in the base frame). n = 15.
- ``gyro``: the gyro drives the rotation, velocity is a random walk; ``b`` the gyro bias. n = 12.
- ``cv``: no IMU: constant velocity and constant body angular rate ``b`` (= omega), both random walks.
  n = 12.
"""

from __future__ import annotations

import math

import numpy as np

from ...geometry import so3_exp_one, so3_log_one

R_, P_, V_, B_, BA_, CR_, CP_ = slice(0, 9), slice(9, 12), slice(12, 15), slice(15, 18), slice(18, 21), \
    slice(21, 30), slice(30, 33)
NX = 33
TH, DP, DV, DB, DBA = slice(0, 3), slice(3, 6), slice(6, 9), slice(9, 12), slice(12, 15)
MODELS = ("ins", "gyro", "cv")


class Layout:
    """Sizes and index slices of the error state for one model, with or without a pose clone."""

    def __init__(self, model: str, clone: bool):
        self.model = model
        self.core = 15 if model == "ins" else 12
        self.clone = clone
        self.n = self.core + (6 if clone else 0)
        self.CTH = slice(self.core, self.core + 3)
        self.CP = slice(self.core + 3, self.core + 6)
        self.eye = np.eye(self.n)

    def clone_matrix(self) -> np.ndarray:
        """J with ``P <- J P J^T`` when the current pose is copied into the clone."""
        J = np.eye(self.n)
        J[self.CTH, :] = 0.0
        J[self.CP, :] = 0.0
        J[self.CTH, TH] = np.eye(3)
        J[self.CP, DP] = np.eye(3)
        return J


def new_state(R: np.ndarray, p: np.ndarray, v: np.ndarray, b: np.ndarray, ba: np.ndarray | None = None) -> np.ndarray:
    x = np.zeros(NX)
    x[R_] = np.asarray(R, float).reshape(9)
    x[P_], x[V_], x[B_] = p, v, b
    if ba is not None:
        x[BA_] = ba
    x[CR_] = x[R_]
    x[CP_] = x[P_]
    return x


CLONE_DUMMY_VAR = 1.0  # variance of the unused clone before the first odometry pose (kept invertible)
CV_OMEGA_SIGMA_RADPS = 0.5
GPS_HEADING_SIGMA_RAD = 0.1  # heading found from the first GPS fixes (gps_heading)
GPS_START_POSITION_SIGMA_M = 10.0  # with GPS the start is estimated from every fix, not pinned to the first


def initial_estimate(s, L: Layout, nz, prep) -> tuple[list[float], np.ndarray]:
    """The 3D filter's first state (a list of floats) and covariance from its start ``s`` (``initial.Start``),
    the noise options ``nz`` and the prepared run ``prep`` (``timeline.Prepared``)."""
    b = s.bg if L.model != "cv" else np.zeros(3)
    ba = (np.zeros(3) if s.ba is None else s.ba) if L.core == 15 else None
    x = new_state(s.R, np.zeros(3), s.v, b, ba)
    d = np.zeros(L.n)
    d[0:2] = nz.init_tilt_sigma_rad**2
    d[2] = 1e-12  # the start fixes the world's yaw (or the IMU's orientation does, tightly)
    if s.yaw_from == "gps":
        d[2] = GPS_HEADING_SIGMA_RAD**2
    if s.yaw_from == "handover" and "gps" in prep.use:  # the world is GPS's: the heading is estimated
        d[2] = max(s.yaw_sigma_rad**2, 1e-12) if s.yaw_sigma_rad else GPS_HEADING_SIGMA_RAD**2
    if s.yaw_from == "imu_orientation":
        imu = prep.imu
        first = int(np.flatnonzero(imu.orientation_valid & (imu.stamps_ns >= prep.t0_ns))[0])
        d[0:3] = np.diag(s.R.T @ imu.orientation_cov[first] @ s.R)
    d[3:6] = GPS_START_POSITION_SIGMA_M**2 if "gps" in prep.use else 1e-12
    d[6:9] = s.v_sigma_mps**2
    d[9:12] = (CV_OMEGA_SIGMA_RADPS if L.model == "cv" else s.bg_sigma_radps) ** 2
    if L.core == 15:
        d[12:15] = nz.init_accel_bias_sigma_mps2**2
    if L.clone:
        d[L.core:] = CLONE_DUMMY_VAR
    return x.tolist(), np.diag(d)


def rot(x: np.ndarray) -> np.ndarray:
    return x[R_].reshape(3, 3)


def clone_rot(x: np.ndarray) -> np.ndarray:
    return x[CR_].reshape(3, 3)


def pose(x: np.ndarray) -> np.ndarray:
    T = np.eye(4)
    T[:3, :3] = x[R_].reshape(3, 3)
    T[:3, 3] = x[P_]
    return T


def boxplus(x: np.ndarray, dx: np.ndarray, L: Layout) -> None:
    """Inject an error-state correction into ``x`` in place (p, v, b, ba are contiguous in both)."""
    x[R_] = (x[R_].reshape(3, 3) @ so3_exp_one(dx[0:3])).ravel()
    x[9:9 + L.core - 3] += dx[3:L.core]
    if L.clone:
        x[CR_] = (clone_rot(x) @ so3_exp_one(dx[L.CTH])).ravel()
        x[CP_] += dx[L.CP]


def boxminus(xa: np.ndarray, xb: np.ndarray, L: Layout) -> np.ndarray:
    """The error state ``d`` with ``xa = xb [+] d``."""
    d = np.zeros(L.n)
    d[TH] = so3_log_one(rot(xb).T @ rot(xa))
    d[DP] = xa[P_] - xb[P_]
    d[DV] = xa[V_] - xb[V_]
    d[DB] = xa[B_] - xb[B_]
    if L.core == 15:
        d[DBA] = xa[BA_] - xb[BA_]
    if L.clone:
        d[L.CTH] = so3_log_one(clone_rot(xb).T @ clone_rot(xa))
        d[L.CP] = xa[CP_] - xb[CP_]
    return d


def on_list(step, x: list[float], *args) -> np.ndarray:
    """A process model of this module (array state, in place) applied to a state held as a list of floats
    (the filter loop's, ``step3d``); returns its F."""
    xa = np.array(x)
    F = step(xa, *args)
    x[:] = xa.tolist()
    return F


def skew3(v: np.ndarray) -> np.ndarray:
    x, y, z = float(v[0]), float(v[1]), float(v[2])
    return np.array([[0.0, -z, y], [z, 0.0, -x], [-y, x, 0.0]])


class ProcessNoise:
    """Diagonal process noise ``q = rate * dt + cube * dt^3 / 3`` per error-state component."""

    def __init__(self, L: Layout, noise):
        rate, cube = np.zeros(L.n), np.zeros(L.n)
        qa, qw = noise.cv_accel_density**2, noise.cv_angular_accel_density**2
        if L.model == "cv":
            rate[DV], cube[DP] = qa, qa
            cube[TH] = qw
            rate[DB] = qw
        if L.model == "gyro":
            rate[TH] = noise.gyro_noise_density**2
            rate[DV], cube[DP] = qa, qa
        if L.model == "ins":
            rate[TH] = noise.gyro_noise_density**2
            rate[DV] = noise.accel_noise_density**2
        if L.model in ("ins", "gyro"):
            rate[DB] = noise.gyro_bias_walk**2
        if L.model == "ins":
            rate[DBA] = noise.accel_bias_walk**2
        rate[:L.core] = np.maximum(rate[:L.core], 1e-16)  # keeps P_pred invertible for the smoother
        self.rate, self.cube = rate, cube / 3.0
        self._has_cube = bool(np.any(cube))

    def __call__(self, dt: float) -> np.ndarray:
        if not self._has_cube:  # the ins model: adding zeros would change nothing but the time
            return self.rate * dt
        return self.rate * dt + self.cube * (dt * dt * dt)


def ins_step(x: np.ndarray, dt: float, w_b: np.ndarray, f_b: np.ndarray, L: Layout, g: np.ndarray) -> np.ndarray:
    """Strapdown step with base-frame rate ``w_b`` and specific force ``f_b`` (raw, biases included)."""
    R = x[R_].reshape(3, 3)
    dR = so3_exp_one((w_b - x[B_]) * dt)
    fc = f_b - x[BA_]
    Rfc = R @ fc
    a = Rfc + g
    x[P_] += (x[V_] + (0.5 * dt) * a) * dt
    x[V_] += a * dt
    Rf = skew3(Rfc) @ R  # = R [fc]x
    F = L.eye.copy()
    F[0:3, 0:3] = dR.T
    F[0, 9] = F[1, 10] = F[2, 11] = -dt
    F[3, 6] = F[4, 7] = F[5, 8] = dt
    h = -0.5 * dt * dt
    F[3:6, 0:3] = h * Rf
    F[3:6, 12:15] = h * R
    F[6:9, 0:3] = -dt * Rf
    F[6:9, 12:15] = -dt * R
    x[R_] = (R @ dR).ravel()
    return F


def gyro_step(x: np.ndarray, dt: float, w_b: np.ndarray, L: Layout) -> np.ndarray:
    """Rotation from the gyro, position from the (random-walk) velocity."""
    dR = so3_exp_one((w_b - x[B_]) * dt)
    x[P_] += x[V_] * dt
    x[R_] = (rot(x) @ dR).reshape(9)
    F = L.eye.copy()
    F[TH, TH] = dR.T
    F[0, 9] = F[1, 10] = F[2, 11] = -dt
    F[3, 6] = F[4, 7] = F[5, 8] = dt
    return F


def cv_step(x: np.ndarray, dt: float, L: Layout) -> np.ndarray:
    """Constant velocity and body angular rate (``b`` = omega)."""
    dR = so3_exp_one(x[B_] * dt)
    x[P_] += x[V_] * dt
    x[R_] = (rot(x) @ dR).reshape(9)
    F = L.eye.copy()
    F[TH, TH] = dR.T
    F[0, 9] = F[1, 10] = F[2, 11] = dt
    F[3, 6] = F[4, 7] = F[5, 8] = dt
    return F


GAP_TAU_S = 2.0  # velocity memory across a gap (first-order Gauss-Markov)


def hold_step(x: np.ndarray, dt: float, L: Layout, tau_s: float = GAP_TAU_S) -> np.ndarray:
    """Across a gap (of the IMU, or of every motion source): rotation held, velocity decaying as a
    first-order Gauss-Markov process, ``v <- v e``, ``p <- p + v tau (1 - e)`` with ``e = exp(-dt/tau)``:
    constant velocity over a short gap, at most ``v tau`` of travel over an hour-long one."""
    e = math.exp(-dt / tau_s)
    x[P_] += x[V_] * (tau_s * (1.0 - e))
    x[V_] *= e
    if L.model == "cv":
        x[B_] *= e
    F = L.eye.copy()
    F[3, 6] = F[4, 7] = F[5, 8] = tau_s * (1.0 - e)
    F[6, 6] = F[7, 7] = F[8, 8] = e
    if L.model == "cv":
        F[9, 9] = F[10, 10] = F[11, 11] = e
    return F


def gap_noise(L: Layout, noise, dt: float, tau_s: float = GAP_TAU_S, since_s: float = 0.0,
              rate_radps: float = 0.0) -> np.ndarray:
    """Process noise of ``hold_step``: the Gauss-Markov velocity (stationary variance ``q tau / 2``), its
    position random walk (``q dt^3 / 3`` at first, ``q tau^2 dt`` in the long run), a rotation error
    capped at pi^2 (any heading), and the biases' random walks.

    ``since_s``: how long the gap had lasted when this step starts. A gap crossed in several steps (split by
    the updates and outputs inside it) gets the position and rotation noise of one step across it: the cubic
    terms grow with the whole gap's length, and summed per piece they would fall far short (ten 0.1 s steps give
    1/100 of one 1 s step's). ``rate_radps``: the turn rate when the gap began (the last gyro sample):
    the held rotation falls behind by up to that rate times the gap's length, a rotation variance of
    ``rate^2 t^2`` on top of the angular-acceleration term."""
    qa, qw = noise.cv_accel_density**2, noise.cv_angular_accel_density**2
    q = np.full(L.n, 1e-16)
    e2 = math.exp(-2.0 * dt / tau_s)
    a, b = since_s, since_s + dt
    q[DV] = 0.5 * qa * tau_s * (1.0 - e2)
    q[DP] = min(qa * b**3 / 3.0, qa * tau_s * tau_s * b) - min(qa * a**3 / 3.0, qa * tau_s * tau_s * a)
    r2 = rate_radps * rate_radps
    q[TH] = min(qw * b**3 / 3.0 + r2 * b * b, math.pi**2) - min(qw * a**3 / 3.0 + r2 * a * a, math.pi**2)
    if L.model == "cv":
        q[DB] = 0.5 * qw * tau_s * (1.0 - e2)
    else:
        q[DB] = noise.gyro_bias_walk**2 * dt
    if L.core == 15:
        q[DBA] = noise.accel_bias_walk**2 * dt
    return q
