"""The 3D error-state EKF over a prepared event stream (lecture: predict from the IMU, update from scan
matching; robot_localization's sensor set: wheel twist, IMU orientation, GPS).

Prediction: the IMU (``ins``: gyro + accelerometer, midpoint of the two samples around each step), the
gyro alone (``gyro``), or constant velocity without an IMU (``cv``). An IMU gap (a pause longer than the
gap threshold, or time outside the IMU's data) is crossed in ONE hold step with inflated noise, whatever
its length. Updates: odometry poses (absolute, tied to the fused world at the first one) or increments
between consecutive odometry poses (a clone of the pose at the previous odometry stamp joins the state),
wheel body velocity (forward speed with the non-holonomic constraint, or the measured components) and yaw
rate, GPS position (ENU about the first fix; the start position is then estimated, not pinned), the IMU's
orientation. Each update passes a chi-square gate (``FuseOptions.gate_probability``); rejections are counted
per source and reason. An output at the stamp of another event is handled with it (``folded_outputs``).
"""

from __future__ import annotations

import numpy as np

from ...geometry import inv_pose, so3_exp_one
from . import measure3d as m3
from . import step3d
from .initial import Start, initial_state
from .gps_quality import GpsNoise, JumpReadmit, noise_variance
from .gyro_gaps import in_gyro_gap
from .inputs import FuseOptions
from .kalman import Anchor, Gate, KnotLog, consider_update
from .rest import REST_RATE_SIGMA_RADPS, at_rest
from .result import pose_covariance_index
from .sanitize import median_period_ns
from .state3d import (
    CP_, CR_, DB, DP, DV, P_, R_, TH, V_, Layout, ProcessNoise, boxminus, cv_step, gap_noise, gyro_step, hold_step,
    initial_estimate, on_list, pose, rot,
)
from .timeline import GPS, IMU, ODOM, WHEEL, Prepared, folded_outputs, gap_free_until, in_coverage_gap
from .update3d import Updater

# P = (P + P^T) / 2 every this many steps while P stays inside the filter (the products' rounding-level asymmetry
# cannot grow); every step when P is recorded (smoother, --cov): what leaves the filter is exactly symmetric
SYMMETRIZE_EVERY = 16


def model_for(use: dict[str, set[str]]) -> str:
    imu = use.get("imu", set())
    return "ins" if "accel" in imu else ("gyro" if "gyro" in imu else "cv")


class Ekf3d:
    """One filter pass. ``run()`` returns the knot record (see ``kalman.KnotLog``)."""

    def __init__(self, prep: Prepared, options: FuseOptions, start: Start | None = None):
        self.prep, self.o, self.noise = prep, options, options.noise
        self.handed: tuple | None = None  # (t_ns, x, P): the filtered state at options.handover_ns (``pieces``)
        self.L = Layout(model_for(prep.use), clone="delta" in prep.use.get("odom", ()))
        self.q = ProcessNoise(self.L, self.noise)
        self.cover_starts, self.cover_ends = [a for a, _ in prep.coverage], [b for _, b in prep.coverage]
        self.g = np.array([0.0, 0.0, -options.gravity_mps2])
        self.gate = Gate(options.gate_probability, options.gate_max_rejects) if options.gate_probability > 0 else None
        self.start = start or initial_state(prep, options.standing_window_ns, options.gravity_mps2, self.noise)
        imu = prep.imu
        self.imu_list = imu.stamps_ns.tolist() if imu is not None else []
        # per-sample values, read as Python floats a sample at a time only off the whole-interval midpoints
        self.imu_w, self.imu_f = prep.imu_w_b, prep.imu_f_b
        self.imu_mid = step3d.interval_midpoints(imu.stamps_ns, prep.imu_w_b, prep.imu_f_b) if imu is not None else None
        self.imu_R = prep.imu_R_wb.reshape(-1, 9).tolist() if prep.imu_R_wb is not None else None
        self.imu_R_var = step3d.isotropic_variances(imu.orientation_cov) if self.imu_R is not None else None
        self.imu_R_cov = imu.orientation_cov if self.imu_R is not None else None
        self.imu_rep, self.wheel_rep = prep.reports.get("imu"), prep.reports.get("wheel")
        self.imu_gap = prep.imu_gap_ns
        period = median_period_ns(imu.stamps_ns) if imu is not None else 0
        self.gyro_var = self.noise.gyro_noise_density**2 / (period * 1e-9) if period > 0 else 0.0
        self.resting = at_rest(prep.rest, prep.imu.stamps_ns) if self.L.model != "cv" and prep.imu is not None \
            else None
        self.bias_states = np.isin(np.arange(self.L.n), np.arange(self.L.n)[DB])  # what a filtered rest update changes
        self.smooth = options.smooth
        self.cov_index = pose_covariance_index(TH, DP)
        self.log = KnotLog(options.smooth, self.cov_index if options.want_covariance else None)
        self.inject = step3d.injector(self.L)  # on the state list
        self.update = Updater(self.gate, self.inject)
        # with nothing measuring the heading, the wheels' body velocity must not turn it: the gyro knows it far
        # better than a slipping wheel's speed against an uncertain velocity
        absolute = {"gps", "odom"} & set(prep.use) or "orientation" in prep.use.get("imu", ())
        self.hold_heading = None if absolute or self.L.model == "cv" else [2, DB.start + 2]
        self.ins = step3d.InsPredictor(self.L, self.g) if self.L.model == "ins" else None
        self._T = np.empty((self.L.n, self.L.n))  # scratch for the covariance products
        self._H_orientation = np.zeros((3, self.L.n))
        self._H_orientation[:, TH] = np.eye(3)
        self._H_velocity = [np.zeros((m, self.L.n)) for m in range(4)]
        w = prep.wheel
        if w is not None:
            self.wheel_yaw_rate = "yaw_rate" in prep.use["wheel"]
            self.wheel_rows = step3d.wheel_velocity_rows(w.velocity_mps, w.velocity_var, prep.use["wheel"],
                                                         self.noise.nonholonomic_sigma_mps,
                                                         self.noise.nonholonomic_rel_sigma)
        self.T_world_odom: np.ndarray | None = None
        self.odom_prev: int | None = None
        self.gps_offset: np.ndarray | None = None
        self.gps_h, self.gps_v = GpsNoise(2), GpsNoise(1)
        self.jumps = JumpReadmit(prep.gps, prep.reports["gps"]) if prep.gps is not None else None
        self.pending_clone = False
        self.J = self.L.clone_matrix() if self.L.clone else None
        self.anchor = Anchor.of(prep)  # no wheel-speed gate reset while a pose source is being accepted
        # no odometry gate reset while GPS is being accepted: odometry that lost track (tens of metres off) then
        # disagrees with GPS and the IMU, and each reset inflated P until the filter diverged
        self.gps_anchor = Anchor.of_gps(prep)
        self.ii = -1  # index of the last IMU sample at or before the current time
        gg = prep.gyro_gaps
        self.gap_yaw = gg.yaw_radps if gg is not None and self.L.model != "cv" else None
        self.gap_wz: float | None = None  # the last wheel yaw rate inside the gyro gap being crossed

    def gyro_gap_at(self, t: int) -> bool:
        """Inside a gap of the gyro (between two IMU samples further apart than its gap threshold)."""
        return bool(in_gyro_gap(self.prep.imu.stamps_ns, self.prep.imu_gap_ns, np.array([t], np.int64))[0])

    def _imu_at(self, t_a: int, t_b: int) -> tuple[list[float], list[float]] | None:
        """Base rate and specific force (3 floats each) at the midpoint of [t_a, t_b] (inside one IMU
        interval), or None where the IMU has a gap or no data."""
        i, st = self.ii, self.imu_list
        if i < 0:
            return None
        if t_a == st[i] and i + 1 < len(st) and t_b == st[i + 1] and t_b - t_a <= self.imu_gap:
            return self.imu_mid[0][i], self.imu_mid[1][i]  # the whole interval: its midpoint, worked out once
        if i + 1 >= len(st) or st[i + 1] - st[i] > self.imu_gap or t_b > st[i + 1]:
            if t_a == t_b == st[i]:
                return self.imu_w[i].tolist(), self.imu_f[i].tolist()
            return None
        a = (0.5 * (t_a + t_b) - st[i]) / (st[i + 1] - st[i])
        (w0, w1, w2), (v0, v1, v2) = self.imu_w[i:i + 2].tolist()
        (f0, f1, f2), (g0, g1, g2) = self.imu_f[i:i + 2].tolist()
        return ([w0 + a * (v0 - w0), w1 + a * (v1 - w1), w2 + a * (v2 - w2)],
                [f0 + a * (g0 - f0), f1 + a * (g1 - f1), f2 + a * (g2 - f2)])

    def _propagate(self, x: list[float], P: np.ndarray, t_a: int, t_b: int) -> None:
        """Predict x and P (in place) from t_a to t_b."""
        dt = (t_b - t_a) * 1e-9
        L = self.L
        gap = False
        if t_a >= self.gap_free_until:  # searched only past the end of the covered stretch last seen
            gap = in_coverage_gap(self.cover_starts, self.cover_ends, t_a, t_b)
            self.gap_free_until = gap_free_until(self.cover_starts, self.cover_ends, t_b)
        if gap:  # no motion data there
            F, q = on_list(hold_step, x, dt, L), gap_noise(L, self.noise, dt)
        elif L.model == "cv":
            F, q = on_list(cv_step, x, dt, L), self.q(dt)
        else:
            u = self._imu_at(t_a, t_b)
            if u is not None and self.ins is not None:
                F = self.ins.propagate(x, P, self._P_diag, self.q.rate, dt, u[0], u[1])
                if self.smooth:
                    self.Phi = F @ self.Phi
                return
            elif u is None:  # an IMU gap (or before its first sample): noise from where it started
                ii = self.ii
                since = t_a - (self.imu_list[ii] if ii >= 0 else self.prep.t0_ns)
                rate = float(np.linalg.norm(self.imu_w[ii])) if ii >= 0 else 0.0
                F = on_list(hold_step, x, dt, L)
                if self.gap_wz is not None:  # the wheels' yaw rate turns the heading and the velocity (``gyro_gaps``)
                    dR = so3_exp_one(np.array([0.0, 0.0, self.gap_wz * dt]))
                    R = rot(np.array(x))
                    Rw = R @ dR @ R.T
                    x[R_] = (R @ dR).reshape(9).tolist()
                    x[V_] = (Rw @ np.array(x[V_])).tolist()
                    F[TH, TH] = dR.T
                    F[DV, :] = Rw @ F[DV, :]
                q = gap_noise(L, self.noise, dt, since_s=max(since, 0) * 1e-9, rate_radps=rate)
            else:
                F, q = on_list(gyro_step, x, dt, np.array(u[0]), L), self.q(dt)
        np.dot(F.dot(P), F.T, out=P)
        self._P_diag += q
        if self.smooth:
            self.Phi = F @ self.Phi

    # -- updates ---------------------------------------------------------------------------------
    def _update(self, t: int, x, P, r, H, Rn, source: str, kind: str, allow_reset: bool = True) -> None:
        """A measurement ``r, H, Rn`` (measure3d's) at t: x and P updated in place."""
        self._open(t, x, P)
        PHt = P.dot(H.T)
        status = self.update(x, P, r.tolist(), PHt, (H.dot(PHt) + Rn).tolist(), H, Rn, kind, allow_reset)
        self.prep.reports[source].outcome(kind, status)
        self.anchor.accepted(source, t, status)
        self.gps_anchor.accepted(source, t, status)

    def _open(self, t: int, x, P) -> None:
        if self.log.open(t, x, P, self.Phi if self.smooth else None) and self.smooth:
            self.Phi = np.eye(self.L.n)

    def _rest(self, t: int, i: int, x, P) -> None:
        """A zero rate: smoothed, an update like any; filtered, only the gyro bias takes it (``consider_update``),
        so the pose does not jump when the robot stops."""
        r, H, Rn = m3.zero_rate(np.array(x), self.prep.imu_w_b[i], self.gyro_var, REST_RATE_SIGMA_RADPS**2, self.L)
        if self.smooth:
            return self._update(t, x, P, r, H, Rn, "imu", "zero_rate")
        self._open(t, x, P)
        P[...] = consider_update(x, P, r, H, Rn, self.inject, self.bias_states)
        self.imu_rep.outcome("zero_rate", "ok")

    def _wheel(self, t: int, i: int, x, P) -> None:
        row = self.wheel_rows[i]
        if row is not None:
            self._body_velocity(t, x, P, *row)
        w = self.prep.wheel
        if self.gap_yaw is not None and np.isfinite(self.gap_yaw[i]):
            self.gap_wz = float(self.gap_yaw[i])
        if self.wheel_yaw_rate and np.isfinite(w.yaw_rate_radps[i]):
            u = None if self.L.model == "cv" else self._imu_at(t, t)
            if self.L.model != "cv" and u is None:
                if self.gap_yaw is not None and self.gyro_gap_at(t):  # the selection's own rate bridges the gap
                    self.gap_wz = float(w.yaw_rate_radps[i])
                    self.wheel_rep.note("gyro_gap_yaw")
                else:
                    self.wheel_rep.reject("in_gap")
            else:
                r, H, Rn = m3.yaw_rate(np.array(x), w.yaw_rate_radps[i], w.yaw_rate_var[i], None if u is None else u[0],
                                       self.gyro_var, self.L)
                self._update(t, x, P, r, H, Rn, "wheel", "wheel_yaw_rate", allow_reset=self.L.model == "cv")

    def _body_velocity(self, t: int, x, P, comps: list[int], z: list[float], var: list[float]) -> None:
        """The update by components ``comps`` of the base-frame velocity (``step3d.body_velocity``)."""
        self._open(t, x, P)
        H = self._H_velocity[len(comps)]
        r = step3d.body_velocity(x, z, comps, H)
        PHt = P.dot(H.T)
        S = H.dot(PHt).tolist()
        for k in range(len(comps)):
            S[k][k] += var[k]
        # a reset (the wheels disagreed gate_max_rejects times in a row) inflates the velocity only: H's attitude
        # columns ([v_b]x) are the linearisation's lever, not evidence that the attitude is off, and with them
        # inflated a speed disagreement (a wheel slip) turned the heading by tens of degrees. No reset at all while
        # odometry poses or GPS are being accepted (kalman.Anchor): the filter is anchored, the wheels disagree
        self.update.hold = self.hold_heading
        status = self.update(x, P, r, PHt, S, H, var, "wheel_velocity", allow_reset=self.anchor.allows_reset(t),
                             reset_states=DV)
        self.update.hold = None
        self.wheel_rep.outcome("wheel_velocity", status)

    def _odom(self, t: int, i: int, x, P) -> None:
        od, rep = self.prep.odom, self.prep.reports["odom"]
        T = od.poses[i]
        pv, rv = od.position_sigma_m[i] ** 2, od.rotation_sigma_rad[i] ** 2
        if "pose" in self.prep.use["odom"]:
            if self.T_world_odom is None:
                self.T_world_odom = pose(np.array(x)) @ inv_pose(T)
                rep.note("anchor")
                return
            r, H, Rn = m3.pose_absolute(np.array(x), self.T_world_odom @ T, pv, rv, self.L)
            self._update(t, x, P, r, H, Rn, "odom", "odom", allow_reset=self.gps_anchor.allows_reset(t))
            return
        self._open(t, x, P)
        if self.odom_prev is None:
            rep.note("anchor")
        else:
            j = self.odom_prev
            T_rel = inv_pose(od.poses[j]) @ T
            r, H, Rn = m3.pose_delta(np.array(x), T_rel, pv + od.position_sigma_m[j] ** 2,
                                     rv + od.rotation_sigma_rad[j] ** 2, self.L)
            self._update(t, x, P, r, H, Rn, "odom", "odom", allow_reset=self.gps_anchor.allows_reset(t))
        self.odom_prev = i
        self.pending_clone = True

    def _gps(self, t: int, i: int, x, P) -> None:
        """Horizontal, then vertical: each with its own noise (claimed or measured) and gate."""
        g = self.prep.gps
        z = g.position_enu_m[i]
        if self.gps_offset is None:  # the world's origin: the first fix (the start position is estimated)
            if not g.accepted[i]:  # a multipath jump (gps_quality), counted there
                return
            self.gps_offset = -z
            self.prep.reports["gps"].note("anchor")
        # a multipath jump's fix: used only once the filter says it, not the fix, is off
        r = m3.position(np.array(x), z + self.gps_offset, g.cov_m2[i], self.L, g.lever)[0][:2]
        if not self.jumps(i, r, P[DP, DP][:2, :2], self.gps_h.variance(float(g.sigma_h_m[i]) ** 2)):
            return
        for rows, sigma, noise, kind in ((slice(0, 2), g.sigma_h_m, self.gps_h, "gps"),
                                         (slice(2, 3), g.sigma_v_m, self.gps_v, "gps_vertical")):
            r, H, _ = m3.position(np.array(x), z + self.gps_offset, g.cov_m2[i], self.L, g.lever)
            r, H = r[rows], H[rows]
            var = noise_variance(noise, r, H, P, float(sigma[i]) ** 2, self.prep.reports["gps"])
            self._update(t, x, P, r, H, np.eye(len(r)) * var, "gps", kind)

    def _orientation(self, t: int, i: int, x, P) -> None:
        """``measure3d.orientation`` with its H = [I 0] used as a selection: P H^T is P's first columns."""
        self._open(t, x, P)
        c = self.imu_R_var[i]
        r, Rn = step3d.orientation(x, self.imu_R[i], self.imu_R_cov[i], c is not None)
        if c is None:
            S = (self._P_block + Rn).tolist()
        else:  # + c I on Python floats (numpy's add of the 3x3 views costs more than the rest of the step)
            S = self._P_block.tolist()
            S[0][0] += c
            S[1][1] += c
            S[2][2] += c
        status = self.update(x, P, list(r), self._P_cols, S, self._H_orientation, Rn, "orientation")
        self.imu_rep.outcome("orientation", status)

    # -- loop -------------------------------------------------------------------------------------
    def run(self) -> dict[str, np.ndarray]:
        prep = self.prep
        # x: a list of floats (step3d), P: one buffer for the whole run, both in place
        x, P = initial_estimate(self.start, self.L, self.noise, prep)
        PT, self._P_cols, self._P_block = P.T, P[:, TH], P[TH, TH]  # views of it: P H^T and H P H^T for H = [I 0]
        self._P_diag = P.reshape(-1)[:: self.L.n + 1]
        self.Phi = np.eye(self.L.n)
        use_orientation = prep.imu_R_wb is not None
        imu_rep, imu_predicts = self.imu_rep, self.L.model != "cv"
        valid_or = prep.imu.orientation_valid.tolist() if use_orientation else None
        t_cur = self.gap_free_until = prep.t0_ns  # the gap test skips steps starting before gap_free_until
        T, log = self._T, self.log
        sym_every = 1 if self.smooth or self.o.want_covariance else SYMMETRIZE_EVERY
        steps = 0
        ins, st, last_imu, imu_gap, q_rate = self.ins, self.imu_list, len(self.imu_list) - 1, self.imu_gap, self.q.rate
        mid_w, mid_f, P_diag = (*self.imu_mid, self._P_diag) if self.imu_mid is not None else (None, None, None)
        hand = self.o.handover_ns
        for t, kind, i, out in zip(*folded_outputs(prep)):
            if hand is not None and t > hand:  # the filtered state for the next piece, with its covariance
                self.handed = (t_cur, np.array(x), P.copy())
                hand = None
            if t > t_cur:
                steps += 1
                if steps % sym_every == 0:
                    np.add(P, PT, out=T)  # P = 0.5 (P + P^T)
                    np.multiply(T, 0.5, out=P)
                log.close(x, P)
                if self.pending_clone:
                    x[CR_], x[CP_] = x[R_], x[P_]
                    P[...] = self.J @ P @ self.J.T
                    if self.smooth:
                        self.Phi = self.J @ self.Phi
                    self.pending_clone = False
                ii = self.ii  # a whole IMU interval inside covered time (the usual step): straight to the kernel
                if ins is not None and t_cur < self.gap_free_until and 0 <= ii < last_imu and t_cur == st[ii] \
                        and t == st[ii + 1] and t - t_cur <= imu_gap:
                    F = ins.propagate(x, P, P_diag, q_rate, (t - t_cur) * 1e-9, mid_w[ii], mid_f[ii])
                    if self.smooth:
                        self.Phi = F @ self.Phi
                else:
                    self._propagate(x, P, t_cur, t)
                t_cur = t
            if kind == IMU:
                self.ii = i
                self.gap_wz = None
                if imu_predicts:
                    imu_rep.predictions += 1
                if use_orientation and valid_or[i]:
                    self._orientation(t, i, x, P)
                if self.resting is not None and self.resting[i]:  # no turn: the gyro reads its bias (``rest``)
                    self._rest(t, i, x, P)
            elif kind == WHEEL:
                self._wheel(t, i, x, P)
            elif kind == ODOM:
                self._odom(t, i, x, P)
            elif kind == GPS:
                self._gps(t, i, x, P)
            if out:  # an output (after every update at t): the open knot's state
                if not log.is_open:
                    self._open(t, x, P)
                log.mark_output()
        self.log.close(x, 0.5 * (P + P.T))
        return self.log.arrays()

    def boxplus(self, x: np.ndarray, dx: np.ndarray) -> None:
        step3d.boxplus(x, dx, self.L)

    def boxminus(self, xa: np.ndarray, xb: np.ndarray) -> np.ndarray:
        return boxminus(xa, xb, self.L)
