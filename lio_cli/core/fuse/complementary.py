"""The lecture's complementary filter, on SO(3) x R^3.

Lecture: ``theta_fused = alpha * theta_scan + (1 - alpha) * (theta_prev + omega_gyro * dt)``. Here the
prediction ``theta_prev + omega dt`` is ``R exp(omega dt)`` with the gyro (bias from a standing start),
else the wheel yaw rate, else the rate between the last two odometry poses; translation follows the wheel
body velocity (forward speed, no side slip), else the velocity between the last two odometry poses, else the
accelerometer (``v += (R f + g) dt``). Each odometry pose then blends in with weight ``alpha_odom``
(``R <- R exp(alpha log(R^T R_scan))``, ``p <- p + alpha (p_scan - p)``; with relative odometry the
"scan" pose is the fused pose at the previous odometry stamp composed with the increment), the IMU's
orientation with ``alpha_orientation`` and GPS positions with ``alpha_gps``. No covariance.
With GPS and no absolute heading, the start heading comes from an EKF pass over the first fixes.
"""

from __future__ import annotations

import math

import numpy as np

from ...geometry import inv_pose, so3_exp_one, so3_log_one
from .initial import Start, initial_state
from .inputs import FuseOptions
from .result import FuseResult, anchor_to_origin, enu_origin
from .state3d import GAP_TAU_S
from .timeline import GPS, IMU, ODOM, OUT, WHEEL, Prepared, in_coverage_gap


def blend_rotation(R_pred: np.ndarray, R_meas: np.ndarray, alpha: float) -> np.ndarray:
    """``alpha`` of the way from ``R_pred`` to ``R_meas`` along the geodesic (the lecture's weighted sum)."""
    return R_pred @ so3_exp_one(alpha * so3_log_one(R_pred.T @ R_meas))


class Complementary:
    def __init__(self, prep: Prepared, options: FuseOptions, start: Start | None = None):
        self.prep, self.o = prep, options
        self.start = start or initial_state(prep, options.standing_window_ns, options.gravity_mps2, options.noise)
        imu_use = prep.use.get("imu", set())
        self.gyro = prep.imu is not None and "gyro" in imu_use
        self.accel = prep.imu is not None and "accel" in imu_use
        self.g = np.array([0.0, 0.0, -options.gravity_mps2])
        self.R, self.p, self.v = self.start.R.copy(), np.zeros(3), self.start.v.copy()
        self.bg = self.start.bg.copy()
        self.vb_wheel: np.ndarray | None = None  # last wheel body velocity
        self.w_wheel: float | None = None
        self.w_odom = np.zeros(3)  # body rate between the last two odometry poses
        self.v_odom: np.ndarray | None = None  # world velocity between the last two odometry poses
        self.T_world_odom: np.ndarray | None = None
        self.odom_prev: tuple[int, int, np.ndarray] | None = None  # (index, stamp, fused pose there)
        self.gps_offset: np.ndarray | None = None
        self.ii = -1
        self.cover_starts, self.cover_ends = [a for a, _ in prep.coverage], [b for _, b in prep.coverage]

    def _imu_rate(self, t_a: int, t_b: int):
        st = self.prep.imu.stamps_ns
        i = self.ii
        if i < 0 or i + 1 >= len(st) or st[i + 1] - st[i] > self.prep.imu_gap_ns:
            return None
        a = (0.5 * (t_a + t_b) - st[i]) / (st[i + 1] - st[i])
        W, Fb = self.prep.imu_w_b, self.prep.imu_f_b
        return W[i] + a * (W[i + 1] - W[i]), Fb[i] + a * (Fb[i + 1] - Fb[i])

    def _predict(self, t_a: int, t_b: int) -> None:
        dt = (t_b - t_a) * 1e-9
        if in_coverage_gap(self.cover_starts, self.cover_ends, t_a, t_b):
            e = math.exp(-dt / GAP_TAU_S)  # no motion data: the last speed fades, as in the EKFs
            self.p = self.p + self.v * (GAP_TAU_S * (1.0 - e))
            self.v = self.v * e
            self.vb_wheel = None
            return
        u = self._imu_rate(t_a, t_b) if (self.gyro or self.accel) else None
        if self.gyro and u is not None:
            w = u[0] - self.bg
        elif self.w_wheel is not None:
            w = np.array([0.0, 0.0, self.w_wheel])
        else:
            w = self.w_odom
        R0 = self.R
        self.R = R0 @ so3_exp_one(w * dt)
        if self.vb_wheel is not None:
            self.v = 0.5 * (R0 + self.R) @ self.vb_wheel
            self.p = self.p + self.v * dt
        elif self.accel and u is not None:
            a = 0.5 * (R0 + self.R) @ u[1] + self.g
            self.p = self.p + self.v * dt + 0.5 * a * dt * dt
            self.v = self.v + a * dt
        else:
            self.p = self.p + self.v * dt

    def _pose(self) -> np.ndarray:
        T = np.eye(4)
        T[:3, :3], T[:3, 3] = self.R, self.p
        return T

    def _odom(self, t: int, i: int) -> None:
        od, rep = self.prep.odom, self.prep.reports["odom"]
        T = od.poses[i]
        a = self.o.alpha_odom
        if "pose" in self.prep.use["odom"]:
            if self.T_world_odom is None:
                self.T_world_odom = self._pose() @ inv_pose(T)
                rep.note("anchor")
                self.odom_prev = (i, t, self._pose())
                return
            Z = self.T_world_odom @ T
        else:
            if self.odom_prev is None:
                rep.note("anchor")
                self.odom_prev = (i, t, self._pose())
                return
            j, _, T_fused_prev = self.odom_prev
            Z = T_fused_prev @ inv_pose(od.poses[j]) @ T
        j, t_prev, T_prev = self.odom_prev
        dt = (t - t_prev) * 1e-9
        e = Z[:3, 3] - self.p
        if dt > 0:
            Zp = self.T_world_odom @ od.poses[j] if self.T_world_odom is not None else T_prev
            self.w_odom = so3_log_one(Zp[:3, :3].T @ Z[:3, :3]) / dt
            if self.vb_wheel is None and not self.accel:
                self.v = self.v + a * ((Z[:3, 3] - Zp[:3, 3]) / dt - self.v)
            else:  # second-order complementary filter: the position error also steers the velocity
                self.v = self.v + (0.25 * a * a) * e / dt
        self.R = blend_rotation(self.R, Z[:3, :3], a)
        self.p = self.p + a * e
        rep.updates += 1
        self.odom_prev = (i, t, self._pose())

    def run(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        prep, o = self.prep, self.o
        stamps, poses, vels = [], [], []
        t_cur = prep.t0_ns
        for t, kind, i in zip(prep.times.tolist(), prep.kinds.tolist(), prep.index.tolist()):
            if t > t_cur:
                self._predict(t_cur, t)
                t_cur = t
            if kind == IMU:
                self.ii = i
                if self.gyro:
                    prep.reports["imu"].predictions += 1
                if prep.imu_R_wb is not None and prep.imu.orientation_valid[i]:
                    self.R = blend_rotation(self.R, prep.imu_R_wb[i], o.alpha_orientation)
                    prep.reports["imu"].updates += 1
            elif kind == WHEEL:
                w, use = prep.wheel, prep.use["wheel"]
                vel = w.velocity_mps[i]
                if ({"speed", "velocity"} & use) and np.isfinite(vel[0]):
                    vb = np.zeros(3) if "speed" in use else np.nan_to_num(vel)
                    vb[0] = vel[0]
                    self.vb_wheel = vb
                if "yaw_rate" in use and np.isfinite(w.yaw_rate_radps[i]):
                    self.w_wheel = float(w.yaw_rate_radps[i])
                prep.reports["wheel"].updates += 1
            elif kind == ODOM:
                self._odom(t, i)
            elif kind == GPS:
                if not prep.gps.accepted[i]:  # a multipath jump (gps_quality), counted there
                    continue
                z = prep.gps.position_enu_m[i]
                if prep.gps.lever is not None:  # the base under the antenna, at the current attitude
                    z = z - self.R @ prep.gps.lever
                if self.gps_offset is None:  # ENU about the first fix, where the state is then
                    self.gps_offset = self.p - z
                    prep.reports["gps"].note("anchor")
                self.p = self.p + o.alpha_gps * (z + self.gps_offset - self.p)
                prep.reports["gps"].updates += 1
            elif kind == OUT:
                stamps.append(t)
                poses.append(self._pose())
                vels.append(self.v.copy())
        return np.asarray(stamps, np.int64), np.asarray(poses).reshape(-1, 4, 4), np.asarray(vels).reshape(-1, 3)


def run_complementary(prep: Prepared, o: FuseOptions, start: Start | None = None) -> FuseResult:
    cf = Complementary(prep, o, start)
    stamps, poses, vels = cf.run()
    info = {"model": "complementary", "start": cf.start.reason, "world_yaw_from": cf.start.yaw_from,
            "odom_mode": next(iter(prep.use.get("odom", ())), None),
            "alpha": {"odom": o.alpha_odom, "orientation": o.alpha_orientation, "gps": o.alpha_gps}}
    origin = enu_origin(poses, None if cf.gps_offset is None else -cf.gps_offset)
    return FuseResult(stamps, anchor_to_origin(poses), None, vels, "complementary", False, prep.reports, info, origin)
