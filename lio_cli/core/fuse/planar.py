"""The lecture's planar EKF for ground robots: state ``[x, y, theta, v, omega, b_omega]``.

Predict (lecture, wheel odometry kinematics): ``x += v cos(theta) dt``, ``y += v sin(theta) dt``,
``theta += omega dt``; ``v``, ``omega`` and the gyro bias ``b_omega`` are random walks. Updates: the gyro's
yaw rate ``omega + b_omega`` (each IMU sample, base z axis), wheel speed ``v`` and yaw rate ``omega``,
odometry poses ``(x, y, theta)`` (absolute, or increments via a clone ``[x_c, y_c, theta_c]``), GPS
``(x, y)``, the IMU orientation's yaw. The accelerometer is not used. Output poses are planar (z, roll and
pitch zero; a smoothed run's height is set after, ``heave``) with covariance only in x, y and yaw. With the
gyro, omega's walk is the gyro's (``turn_rate_walk``); smoothed without a position source, the path is the
smoothed rates integrated again (``reintegrated``). Inside a gap of the gyro (``gyro_gaps``) the turn rate decays
and the wheels' yaw rate, where they have one, updates it.
"""

from __future__ import annotations

import math

import numpy as np

from ...geometry import inv_pose, yaw_of
from .initial import Start, initial_state
from .gps_quality import GpsNoise, JumpReadmit, noise_variance
from .graph import odom_spin
from .inputs import FuseOptions
from .kalman import Anchor, Gate, KnotLog, consider_update, kalman_update
from .sanitize import median_period_ns
from .state3d import CLONE_DUMMY_VAR, GAP_TAU_S, GPS_HEADING_SIGMA_RAD, GPS_START_POSITION_SIGMA_M
from .rest import REST_RATE_SIGMA_RADPS, at_rest
from .planar_model import (BW, TH, V, W, X, Y, delta_residual, predict, predict_gap, predict_turn_decay,
                           turn_rate_walk, wrap)
from .timeline import GPS, IMU, ODOM, OUT, WHEEL, Prepared, in_coverage_gap

OMEGA0_SIGMA_RADPS = 0.5
CLONE_JITTER = 1e-9  # of the pose's variance, the clone's own (relative) ...
CLONE_JITTER_FLOOR = 1e-14  # ... and at least this (m^2, rad^2)


class PlanarEkf:
    def __init__(self, prep: Prepared, options: FuseOptions, start: Start | None = None):
        self.prep, self.o, self.nz = prep, options, options.noise
        self.clone = "delta" in prep.use.get("odom", ())
        self.n = 9 if self.clone else 6
        self.start = start or initial_state(prep, options.standing_window_ns, options.gravity_mps2, self.nz)
        self.gate = Gate(options.gate_probability, options.gate_max_rejects) if options.gate_probability > 0 else None
        imu_use = prep.use.get("imu", set())
        self.use_gyro = prep.imu is not None and "gyro" in imu_use
        period = median_period_ns(prep.imu.stamps_ns) if prep.imu is not None else 0
        self.gyro_var = self.nz.gyro_noise_density**2 / (period * 1e-9) if period > 0 else 0.0
        nz = self.nz
        self.q_rate = np.zeros(self.n)
        self.q_rate[V], self.q_rate[W] = nz.cv_accel_density**2, nz.cv_angular_accel_density**2
        if self.use_gyro:  # the gyro measures the turn rate: its walk is how fast the gyro shows it change
            self.q_rate[W] = min(turn_rate_walk(prep.imu.stamps_ns, prep.imu_w_b[:, 2]) ** 2, self.q_rate[W])
        self.q_rate[BW] = max(nz.gyro_bias_walk**2, 1e-16)
        self.q_rate[X] = self.q_rate[Y] = self.q_rate[TH] = 1e-16  # keeps P_pred invertible for the smoother
        self.log = KnotLog(options.smooth, np.array([X, Y, TH]) if options.want_covariance else None)
        self.T_world_odom: np.ndarray | None = None
        self.odom_prev: int | None = None
        self.gps_offset: np.ndarray | None = None
        self.gps_h = GpsNoise(2)
        self.jumps = JumpReadmit(prep.gps, prep.reports["gps"]) if prep.gps is not None else None
        self.pending_clone = False
        self.handed: tuple | None = None  # (t_ns, x, P) of one knot: the filter's state at options.handover_ns
        self.anchor = Anchor.of(prep)  # no wheel-speed gate reset while a pose source is being accepted
        # no odometry gate reset while GPS is being accepted: odometry that lost track (tens of metres off) then
        # disagrees with GPS and the IMU, and each reset inflated P until the filter diverged
        self.gps_anchor = Anchor.of_gps(prep)
        gg = prep.gyro_gaps if self.use_gyro else None
        self.gyro_runs = (gg.run_starts, gg.run_ends) if gg is not None else None
        self.gap_yaw, self.gap_yaw_var = (gg.yaw_radps, gg.yaw_var) if gg is not None else (None, None)
        self.resting = at_rest(prep.rest, prep.imu.stamps_ns) if self.use_gyro else None
        self.rate_states = np.isin(np.arange(self.n), [W, BW])  # what a filtered rest update changes
        # the turn rate is the heading's, not the base z axis's (``level.heading_rate_offset``)
        self.heading_offset = prep.heading_offset if self.use_gyro else None
        self.wheel_heading_offset = None
        if self.heading_offset is not None and prep.wheel is not None:
            self.wheel_heading_offset = np.interp(prep.wheel.stamps_ns, prep.imu.stamps_ns, self.heading_offset)
        # odometry increments turn no looser than their scatter about the gyro's shows, as in the graph
        spin = odom_spin.increment_sigma(prep, np.arange(len(prep.odom))) if self.clone and self.use_gyro else None
        self.odom_turn_var = None if spin is None else (odom_spin.MARGIN * spin) ** 2

    # -- manifold (vector with wrapped angles) ------------------------------------------------------
    def boxplus(self, x: np.ndarray, dx: np.ndarray) -> None:
        x += dx
        x[TH] = wrap(x[TH])
        if self.clone:
            x[8] = wrap(x[8])

    def boxminus(self, xa: np.ndarray, xb: np.ndarray) -> np.ndarray:
        d = xa - xb
        d[TH] = wrap(d[TH])
        if self.clone:
            d[8] = wrap(d[8])
        return d

    def _initial(self) -> tuple[np.ndarray, np.ndarray]:
        s = self.start
        x = np.zeros(self.n)
        x[TH] = float(yaw_of(s.R))
        vb = s.R.T @ s.v
        x[V] = vb[0]
        x[BW] = s.bg[2] if self.use_gyro else 0.0
        d = np.full(self.n, CLONE_DUMMY_VAR)
        d[X] = d[Y] = d[TH] = 1e-12
        if "gps" in self.prep.use:
            d[X] = d[Y] = GPS_START_POSITION_SIGMA_M**2
        if s.yaw_from == "gps":
            d[TH] = GPS_HEADING_SIGMA_RAD**2
        if s.yaw_from == "handover" and "gps" in self.prep.use:  # the world is GPS's: the heading is estimated
            d[TH] = max(s.yaw_sigma_rad**2, 1e-12)
        if s.yaw_from == "imu_orientation":
            i = int(np.flatnonzero(self.prep.imu.orientation_valid & (self.prep.imu.stamps_ns >= self.prep.t0_ns))[0])
            d[TH] = self.prep.imu.orientation_cov[i][2, 2]
        d[V] = s.v_sigma_mps**2
        d[W] = OMEGA0_SIGMA_RADPS**2
        d[BW] = s.bg_sigma_radps**2 if self.use_gyro else 1e-6
        return x, np.diag(d)

    def _propagate(self, x: np.ndarray, P: np.ndarray, dt: float, gap: bool = False,
                   gyro_gap: bool = False) -> np.ndarray:
        if gap:  # no motion data: speed and turn rate decay (Gauss-Markov), as in the 3D filter
            F, q = predict_gap(x, dt, self.n), self._gap_noise(dt)
        elif gyro_gap:  # the wheels (or odometry) go on without the gyro: the turn rate decays unless they measure it
            F, q = predict_turn_decay(x, dt, self.n), self.q_rate * dt
            q[W] = 0.5 * self.nz.cv_angular_accel_density**2 * GAP_TAU_S * (1.0 - math.exp(-2.0 * dt / GAP_TAU_S))
        else:
            F, q = predict(x, dt, self.n), self.q_rate * dt
        P = F @ P @ F.T
        P.flat[:: self.n + 1] += q
        if self.o.smooth:
            self.Phi = F @ self.Phi
        return P

    def _gap_noise(self, dt: float) -> np.ndarray:
        nz, tau = self.nz, GAP_TAU_S
        qa, qw = nz.cv_accel_density**2, nz.cv_angular_accel_density**2
        q = self.q_rate * dt
        e2 = math.exp(-2.0 * dt / tau)
        q[V], q[W] = 0.5 * qa * tau * (1.0 - e2), 0.5 * qw * tau * (1.0 - e2)
        q[X] = q[Y] = min(qa * dt**3 / 3.0, qa * tau * tau * dt)
        q[TH] = min(qw * dt**3 / 3.0, math.pi**2)
        return q

    def _open(self, t: int, x, P) -> None:
        if not self.log.is_open:
            self.log.open(t, x, P, self.Phi if self.o.smooth else None)
            if self.o.smooth:
                self.Phi = np.eye(self.n)

    def _update(self, t, x, P, r, H, Rn, source, kind, allow_reset=True):
        self._open(t, x, P)
        P, status = kalman_update(x, P, r, H, Rn, self.boxplus, self.gate, kind, allow_reset)
        self.prep.reports[source].outcome(kind, status)
        self.anchor.accepted(source, t, status)
        self.gps_anchor.accepted(source, t, status)
        return P

    def _row(self, cols: dict[int, float]) -> np.ndarray:
        H = np.zeros((1, self.n))
        for k, val in cols.items():
            H[0, k] = val
        return H

    # -- measurements -------------------------------------------------------------------------------
    def _imu(self, t, i, x, P):
        prep = self.prep
        if self.use_gyro:
            z = prep.imu_w_b[i][2] + (0.0 if self.heading_offset is None else self.heading_offset[i])
            r, H, Rn = np.array([z - x[W] - x[BW]]), self._row({W: 1.0, BW: 1.0}), np.array([[self.gyro_var]])
            if not self.resting[i]:
                P = self._update(t, x, P, r, H, Rn, "imu", "gyro")
            else:  # at rest (``rest``): no turn, so the gyro reads its bias
                P = self._rest(t, x, P, r, H, Rn, "gyro")
                P = self._rest(t, x, P, np.array([-x[W]]), self._row({W: 1.0}),
                               np.array([[REST_RATE_SIGMA_RADPS**2]]), "zero_rate")
        if prep.imu_R_wb is not None and prep.imu.orientation_valid[i]:
            z = float(yaw_of(prep.imu_R_wb[i]))
            P = self._update(t, x, P, np.array([wrap(z - x[TH])]), self._row({TH: 1.0}),
                             np.array([[prep.imu.orientation_cov[i][2, 2]]]), "imu", "orientation")
        return P

    def _rest(self, t, x, P, r, H, Rn, kind):
        """An update at rest. Smoothed, like any (the smoother carries the bias back); filtered, only the rates
        take it (``consider_update``): the filter's pose does not jump when the robot stops."""
        if self.o.smooth:
            return self._update(t, x, P, r, H, Rn, "imu", kind)
        self._open(t, x, P)
        self.prep.reports["imu"].outcome(kind, "ok")
        return consider_update(x, P, r, H, Rn, self.boxplus, self.rate_states)

    def _wheel(self, t, i, x, P):
        w, use = self.prep.wheel, self.prep.use["wheel"]
        if ({"speed", "velocity"} & use) and np.isfinite(w.velocity_mps[i, 0]):
            P = self._update(t, x, P, np.array([w.velocity_mps[i, 0] - x[V]]), self._row({V: 1.0}),
                             np.array([[w.velocity_var[i, 0]]]), "wheel", "wheel_speed",
                             allow_reset=self.anchor.allows_reset(t))
        if "yaw_rate" in use and np.isfinite(w.yaw_rate_radps[i]):
            z = w.yaw_rate_radps[i] + (0.0 if self.wheel_heading_offset is None else self.wheel_heading_offset[i])
            P = self._update(t, x, P, np.array([z - x[W]]), self._row({W: 1.0}),
                             np.array([[w.yaw_rate_var[i]]]), "wheel", "wheel_yaw_rate", allow_reset=not self.use_gyro)
        elif self.gap_yaw is not None and np.isfinite(self.gap_yaw[i]):  # inside a gyro gap: the turn rate
            P = self._update(t, x, P, np.array([self.gap_yaw[i] - x[W]]), self._row({W: 1.0}),
                             np.array([[self.gap_yaw_var[i]]]), "wheel", "gyro_gap_yaw_rate")
        return P

    def _odom(self, t, i, x, P):
        od, rep = self.prep.odom, self.prep.reports["odom"]
        T = od.poses[i]
        pv, rv = od.position_sigma_m[i] ** 2, od.rotation_sigma_rad[i] ** 2
        if not self.clone:
            if self.T_world_odom is None:
                self.T_world_odom = se2(x[X], x[Y], x[TH]) @ inv_pose(_flat(T))
                rep.note("anchor")
                return P
            Z = self.T_world_odom @ _flat(T)
            r = np.array([Z[0, 3] - x[X], Z[1, 3] - x[Y], wrap(float(yaw_of(Z[:3, :3])) - x[TH])])
            H = np.zeros((3, self.n))
            H[0, X] = H[1, Y] = H[2, TH] = 1.0
            return self._update(t, x, P, r, H, np.diag([pv, pv, rv]), "odom", "odom",
                                allow_reset=self.gps_anchor.allows_reset(t))
        self._open(t, x, P)
        if self.odom_prev is None:
            rep.note("anchor")
        else:
            j = self.odom_prev
            r, H = delta_residual(x, inv_pose(_flat(od.poses[j])) @ _flat(T))
            var_p, var_r = pv + od.position_sigma_m[j] ** 2, rv + od.rotation_sigma_rad[j] ** 2
            if self.odom_turn_var is not None:
                var_r = min(var_r, self.odom_turn_var)
            P = self._update(t, x, P, r, H, np.diag([var_p, var_p, var_r]), "odom", "odom",
                             allow_reset=self.gps_anchor.allows_reset(t))
        self.odom_prev = i
        self.pending_clone = True
        return P

    def _gps(self, t, i, x, P):
        g = self.prep.gps
        z = g.position_enu_m[i, :2]
        if self.gps_offset is None:  # the world's origin: the first fix (the start position is estimated)
            if not g.accepted[i]:  # a multipath jump (gps_quality), counted there
                return P
            self.gps_offset = -z
            self.prep.reports["gps"].note("anchor")
        H = np.zeros((2, self.n))
        H[0, X] = H[1, Y] = 1.0
        r = z + self.gps_offset - x[0:2]
        if g.lever is not None:  # the antenna turns with the heading (the body's tilt left out)
            c, s = math.cos(x[TH]), math.sin(x[TH])
            a = g.lever[:2]
            r = r - np.array([c * a[0] - s * a[1], s * a[0] + c * a[1]])
            H[0, TH], H[1, TH] = -s * a[0] - c * a[1], c * a[0] - s * a[1]
        # a multipath jump: used only once the filter says it, not the fix, is off
        if not self.jumps(i, r, P[np.ix_([X, Y], [X, Y])], self.gps_h.variance(float(g.sigma_h_m[i]) ** 2)):
            return P
        var = noise_variance(self.gps_h, r, H, P, float(g.sigma_h_m[i]) ** 2, self.prep.reports["gps"])
        return self._update(t, x, P, r, H, np.eye(2) * var, "gps", "gps")

    def _apply_clone(self, x, P):
        J = np.eye(self.n)
        J[6:9, :] = 0.0
        J[6, X] = J[7, Y] = J[8, TH] = 1.0
        x[6:9] = x[0:3]
        P = J @ P @ J.T
        if self.o.smooth:
            self.Phi = J @ self.Phi
            # an exact copy leaves the covariance singular, which the RTS pass must invert: the clone a hair apart
            P[6:9, 6:9] += np.diag(CLONE_JITTER * np.diag(P)[0:3] + CLONE_JITTER_FLOOR)
        return P

    def run(self) -> dict[str, np.ndarray]:
        prep = self.prep
        x, P = self._initial()
        self.Phi = np.eye(self.n)
        t_cur = prep.t0_ns
        starts, ends = [a for a, _ in prep.coverage], [b for _, b in prep.coverage]
        hand = self.o.handover_ns if not self.o.smooth else None  # smoothed: from the smoothed states
        for t, kind, i in zip(prep.times.tolist(), prep.kinds.tolist(), prep.index.tolist()):
            if hand is not None and t > hand:  # the filtered state for the next piece
                self.handed = (np.array([t_cur]), x[None].copy(), P[None].copy())
                hand = None
            if t > t_cur:
                P = 0.5 * (P + P.T)
                self.log.close(x, P)
                if self.pending_clone:
                    P = self._apply_clone(x, P)
                    self.pending_clone = False
                gap = in_coverage_gap(starts, ends, t_cur, t)
                gyro_gap = not gap and self.gyro_runs is not None and in_coverage_gap(*self.gyro_runs, t_cur, t)
                P = self._propagate(x, P, (t - t_cur) * 1e-9, gap, gyro_gap)
                t_cur = t
            if kind == IMU:
                P = self._imu(t, i, x, P)
            elif kind == WHEEL:
                P = self._wheel(t, i, x, P)
            elif kind == ODOM:
                P = self._odom(t, i, x, P)
            elif kind == GPS:
                P = self._gps(t, i, x, P)
            elif kind == OUT:
                self._open(t, x, P)
                self.log.mark_output()
        self.log.close(x, 0.5 * (P + P.T))
        if hand is not None:
            self.handed = (np.array([t_cur]), x[None].copy(), P[None].copy())
        return self.log.arrays()


def se2(x: float, y: float, th: float) -> np.ndarray:
    c, s = math.cos(th), math.sin(th)
    T = np.eye(4)
    T[0, 0], T[0, 1], T[1, 0], T[1, 1], T[0, 3], T[1, 3] = c, -s, s, c, x, y
    return T


def _flat(T: np.ndarray) -> np.ndarray:
    return se2(T[0, 3], T[1, 3], float(yaw_of(T[:3, :3])))
