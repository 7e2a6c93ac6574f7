"""The factors of one chunk of keyframes [k0, k1): what each measurement says about the nav states X (Pose3
``T_world_base``), V (world velocity) and B (IMU biases, base frame) at keyframe k.

- IMU: ``CombinedImuFactor`` between consecutive keyframes (biases' random walk included); an interval with
  an IMU gap gets the filter's own increment instead, loosely (``bridge``).
- Wheels: the increment of position between consecutive keyframes in the first one's base axes, each message's
  base velocity (forward speed and the non-holonomic zeros, as the filter's ``wheel_velocity_rows``) rotated by
  the gyro as preintegrated; a ``BetweenFactorPose3`` whose rotation is left loose (the gyro's), Gaussian (a
  robust loss there took a wheel scale error for outliers and let the IMU drift). Beside odometry: times the
  wheels' speed scale, slips left out, Huber, looser (``wheels``). The wheels' yaw rate where the timeline let
  it in beside the gyro: a factor per interval tight about z only (``wheels.YawTrack``).
- Odometry: absolute poses as ``PriorFactorPose3`` in the world the filter ties them to (``pose``), or
  ``BetweenFactorPose3`` of consecutive poses with the two poses' variances summed, scaled by
  ``ODOM_DELTA_SHARE`` (``delta``).
- GPS: each fix on its keyframe with a slow receiver-error chain (``gps``).
- IMU orientation: a rotation prior at keyframes where the filter used one.
"""

from __future__ import annotations

from functools import cached_property

import gtsam
import numpy as np
from gtsam.symbol_shorthand import B, G, V, X

from ..step3d import wheel_velocity_rows
from ..timeline import Prepared
from . import gps, height, odom_spin, rest, wheels
from .gps import FREE_SIGMA
from .imu import Segments
from .keyframes import MERGE_NS, attach

# wheel increments without a robust loss: a robust one takes a wheel scale error for outliers and lets the graph
# drift on the IMU
WHEEL_HUBER_K: float | None = None
BRIDGE_ACCEL_DENSITY = 1.0  # m/s^2/sqrt(Hz): how far the filter's increment across an IMU gap is trusted
BRIDGE_ROTATION_DENSITY = 0.1  # rad/sqrt(s)
ORIENTATION_MAX_DT_NS = 10_000_000
FREE_VAR = 1e8  # (m/s)^2: a velocity component a wheel message does not give
# odometry increments: their sigma this share of the two poses' summed sigmas (those are absolute-pose sigmas;
# consecutive poses of a scan matcher are far closer to each other than to the truth)
ODOM_DELTA_SHARE = 0.1
# their rotation sigma at most this many times what their scatter about the gyro's shows (``odom_spin``)
ODOM_SPIN_MARGIN = odom_spin.MARGIN
# wheel increments' sigmas times this beside odometry (poses or increments: ODOM_WHEEL_LOOSE_MODES) when their
# scale is not estimated (``WHEEL_SCALE``), so a wheel scale error or a slip cannot pull it off
ODOM_WHEEL_SIGMA_SCALE = 30.0
# beside odometry: the wheel increments times the speed scale a pre-pass finds against the odometry, slips gated
# out, Huber, ``wheels.SIGMA_SCALE`` times their sigma (``wheels``)
WHEEL_SCALE = True
# the wheels' yaw factor's sigma times this beside odometry (poses or increments: ODOM_WHEEL_LOOSE_MODES)
ODOM_YAW_SIGMA_SCALE = 30.0
ODOM_WHEEL_LOOSE_MODES = ("pose", "delta")
# odometry poses' position sigma times this in the graph: a scan matcher's poses share their drift, so one
# independent prior per pose counts them many times over (and pins each keyframe to the pose's noise)
ODOM_POSE_SIGMA_SCALE = 2.0


def _sigmas(sig: np.ndarray):
    return gtsam.noiseModel.Diagonal.Sigmas(sig)


def nav(R: np.ndarray, p: np.ndarray) -> gtsam.Pose3:
    return gtsam.Pose3(gtsam.Rot3(R), p)


class Measurements:
    """Every measurement attached to its keyframe once for the whole log (numpy), so a chunk's graph is a slice."""

    def __init__(self, prep: Prepared, kt: np.ndarray, noise):
        self.prep, self.kt, self.noise = prep, kt, noise
        K = len(kt)
        self.wheel_dp: dict[int, tuple[np.ndarray, np.ndarray]] = {}  # keyframe k -> increment to k+1, sigma
        gps.attach_fixes(self, prep, kt)
        self.odom_pairs = np.zeros((0, 2), np.int64)
        od = prep.odom
        if od is not None and len(od) > 1 and "odom" in prep.use:
            idx = np.flatnonzero((od.stamps_ns >= kt[0]) & (od.stamps_ns < kt[-1] + MERGE_NS))
            self.odom_idx = idx
            self.odom_k = attach(kt, od.stamps_ns[idx])
        else:
            self.odom_idx = np.zeros(0, np.int64)
            self.odom_k = np.zeros(0, np.int64)
        self.orient = [None] * K
        imu = prep.imu
        if prep.imu_R_wb is not None:
            valid = np.flatnonzero(imu.orientation_valid)
            if len(valid):
                j = valid[_nearest(imu.stamps_ns[valid], kt)]
                close = np.abs(imu.stamps_ns[j] - kt) <= ORIENTATION_MAX_DT_NS
                for k in np.flatnonzero(close).tolist():
                    i = j[k]
                    sig = float(np.sqrt(max(np.trace(imu.orientation_cov[i]) / 3.0, 1e-12)))
                    self.orient[k] = (prep.imu_R_wb[i], sig)

    @cached_property
    def odom_spin(self) -> float | None:
        """The odometry increments' rotation sigma their scatter about the gyro's shows (``odom_spin``), where
        the graph takes them as increments beside the gyro; else None."""
        if len(self.odom_idx) < 2 or "delta" not in self.prep.use.get("odom", ()) \
                or "gyro" not in self.prep.use.get("imu", ()):
            return None
        return odom_spin.increment_sigma(self.prep, self.odom_idx)

    @cached_property
    def level(self) -> height.Level | None:
        """The log's height prior (``height.level``), worked out once for every try of the graph."""
        return height.level(self.prep)

    def odom_world(self, s: dict[str, np.ndarray]) -> np.ndarray:
        """The odometry frame in the world: the states ``s`` at the first odometry pose, as the filter ties it."""
        k = int(self.odom_k[0])
        return nav(s["R"][k], s["p"][k]).matrix() @ np.linalg.inv(self.prep.odom.poses[self.odom_idx[0]])


def _nearest(grid: np.ndarray, t: np.ndarray) -> np.ndarray:
    j = np.clip(np.searchsorted(grid, t), 1, max(len(grid) - 1, 1))
    lo = grid[j - 1]
    hi = grid[np.minimum(j, len(grid) - 1)]
    return np.where(t - lo <= hi - t, j - 1, np.minimum(j, len(grid) - 1))


class WheelTrack:
    """The wheel base velocity (components and variances as the filter's ``wheel_velocity_rows``) held over each
    IMU segment from the message nearest its middle; ``ok`` where one lies within a wheel gap of it."""

    def __init__(self, z: np.ndarray, var: np.ndarray, ok: np.ndarray, rel_var: np.ndarray | None = None):
        self.z, self.sigma, self.ok = z, np.sqrt(var), ok
        self.rel_var = np.zeros(len(z)) if rel_var is None else rel_var  # the forward variance's share of the speed

    def without_speed_share(self, floor_var: float) -> WheelTrack:
        """The same track, its forward variance without the configured share of the speed (floored)."""
        var = self.sigma**2
        var[:, 0] = np.maximum(var[:, 0] - self.rel_var, floor_var)
        return WheelTrack(self.z, var, self.ok)

    @classmethod
    def of(cls, prep: Prepared, seg: Segments, noise) -> WheelTrack | None:
        w = prep.wheel
        if w is None or len(w) < 2 or "wheel" not in prep.use:
            return None
        rows = wheel_velocity_rows(w.velocity_mps, w.velocity_var, prep.use["wheel"], noise.nonholonomic_sigma_mps,
                                   noise.nonholonomic_rel_sigma)
        z, var = np.zeros((len(w), 3)), np.full((len(w), 3), FREE_VAR)
        has = np.zeros(len(w), bool)
        for i, row in enumerate(rows):
            if row is not None:
                c = list(row[0])
                z[i, c], var[i, c], has[i] = row[1], row[2], True
        period = float(np.median(np.diff(w.stamps_ns))) * 1e-9
        mid = seg.t + (0.5e9 * seg.dt).astype(np.int64)
        j = _nearest(w.stamps_ns, mid)
        ok = has[j] & (np.abs(w.stamps_ns[j] - mid) <= max(1.5 * period * 1e9, 2.5e7))
        return cls(z[j], var[j], ok, (noise.wheel_speed_rel_sigma * z[j, 0]) ** 2)


class ChunkGraph:
    """Builds the factor graph and the starting values of keyframes [k0, k1)."""

    def __init__(self, meas: Measurements, seg: Segments, params, states: dict[str, np.ndarray]):
        self.m, self.seg, self.params, self.s = meas, seg, params, states
        self.wheel = WheelTrack.of(meas.prep, seg, meas.noise)
        self.yaw = wheels.YawTrack.of(meas.prep, seg.t, seg.dt, _nearest)
        self.bridged = 0
        od = meas.prep.use.get("odom", set())
        self.beside_odom = bool(len(meas.odom_k) and od & set(ODOM_WHEEL_LOOSE_MODES))
        self.scaled = self.wheel is not None and WHEEL_SCALE and self.beside_odom
        self.level = meas.level if self.wheel is not None and self.beside_odom else None
        # beside odometry the wheels' yaw as loose as their speed: their slips' edges and any bias turn the
        # heading over the whole log, the odometry's by far less
        self.yaw_loose = ODOM_YAW_SIGMA_SCALE if self.beside_odom else 1.0
        self.levelled = 0
        self.rested = 0  # keyframe intervals held still (``rest``)
        if self.scaled:  # the forward sigma's share of the speed stood for a scale error: the scale carries it
            self.wheel = self.wheel.without_speed_share(meas.noise.wheel_speed_sigma_mps**2)
        self.scale_start: dict[int, float] = {}  # chunk's first keyframe -> its wheel scale from the pre-pass
        self.wheel_rejected: set[int] = set()  # keyframe intervals left out as slips
        self.bias_seam: dict[int, np.ndarray] = {}  # receiver-error nodes the previous chunk solved (solve)

    def bias(self, k: int) -> gtsam.imuBias.ConstantBias:
        return gtsam.imuBias.ConstantBias(self.s["ba"][k], self.s["bg"][k])

    def values(self, k0: int, k1: int) -> gtsam.Values:
        vals = gtsam.Values()
        s = self.s
        for k in range(k0, k1):
            vals.insert(X(k), nav(s["R"][k], s["p"][k]))
            vals.insert(V(k), s["v"][k])
            vals.insert(B(k), self.bias(k))
        for j in self.gps_bias_nodes(k0, k1).tolist():
            vals.insert(G(j), self.bias_seam.get(j, np.zeros(3)))
        return vals

    def wheel_info(self) -> dict | None:
        """The scaled wheel increments' figures for the metrics, or None without them."""
        if not self.scaled:
            return None
        return {"model": "speed scale per chunk, slips gated against the odometry",
                "scale_from": "odometry (pre-pass)",
                "scale": [round(v, 5) for v in self.scale_start.values()],
                "increments": len(self.m.wheel_dp),
                "rejected": {"slip": {"count": len(self.wheel_rejected), "why": wheels.SLIP_WHY}}
                if self.wheel_rejected else {}}

    def build(self, k0: int, k1: int) -> gtsam.NonlinearFactorGraph:
        g = gtsam.NonlinearFactorGraph()
        m, seg = self.m, self.seg
        wheel_loss = None if WHEEL_HUBER_K is None else gtsam.noiseModel.mEstimator.Huber.Create(WHEEL_HUBER_K)
        scaled: list[tuple[int, np.ndarray, np.ndarray, gtsam.Rot3]] = []
        for k in range(k0, k1 - 1):
            pim = gtsam.PreintegratedCombinedMeasurements(self.params, self.bias(k))
            s0, s1 = seg.at_cut[k], seg.at_cut[k + 1]
            if seg.gap[s0:s1].any():
                self._bridge(g, k)
                continue
            wheel = self.wheel is not None and bool(self.wheel.ok[s0:s1].all())
            dp, sd = seg.integrate_with(pim, s0, s1, self.wheel if wheel else None)
            g.add(gtsam.CombinedImuFactor(X(k), V(k), X(k + 1), V(k + 1), B(k), B(k + 1), pim))
            if self.yaw is not None and self.yaw.ok[s0:s1].all():
                g.add(self.yaw.factor(X(k), X(k + 1), pim.deltaRij(), seg.w[:, 2], float(self.s["bg"][k][2]), seg.dt,
                                      slice(s0, s1), self.yaw_loose))
            if wheel and self.scaled:
                scaled.append((k, dp, sd, pim.deltaRij()))
            elif wheel:
                if self.beside_odom:
                    sd = sd * ODOM_WHEEL_SIGMA_SCALE
                m.wheel_dp[k] = (dp, sd)
                sig = np.r_[np.full(3, wheels.LOOSE_ROTATION_RAD), sd]
                model = _sigmas(sig) if wheel_loss is None else gtsam.noiseModel.Robust.Create(wheel_loss, _sigmas(sig))
                g.add(gtsam.BetweenFactorPose3(X(k), X(k + 1), gtsam.Pose3(pim.deltaRij(), dp), model))
        for k in range(k0, k1):
            o = m.orient[k]
            if o is not None:
                sig = np.r_[np.full(3, o[1]), np.full(3, FREE_SIGMA)]
                g.add(gtsam.PriorFactorPose3(X(k), nav(o[0], self.s["p"][k]), gtsam.noiseModel.Diagonal.Sigmas(sig)))
        gps.add_fixes(g, self.m, self.level, self.gps_bias_nodes(k0, k1), self.bias_seam, k0, k1)
        self._odom(g, k0, k1)
        if scaled:
            self._scaled_wheels(g, k0, scaled)
        if self.level is not None:
            self.levelled += height.add(g, self.level, float(self.s["p"][0, 2]), k0, k1)
        self.rested += rest.add(g, m.kt, m.prep.rest, k0, k1)
        return g

    def _scaled_wheels(self, g, k0: int, incs: list[tuple[int, np.ndarray, np.ndarray, gtsam.Rot3]]) -> None:
        """The chunk's wheel increments times its scale variable, slips gated out (``wheels``)."""
        ks = np.array([inc[0] for inc in incs], np.int64)
        verdict = wheels.gate(self.m.kt, self.s, ks, np.array([inc[1] for inc in incs]))
        out = set(verdict.rejected.tolist())
        self.wheel_rejected |= out
        self.scale_start[k0] = verdict.scale
        for k, dp, sd, dR in incs:
            if k in out:
                self.m.wheel_dp.pop(k, None)
                continue
            self.m.wheel_dp[k] = (verdict.scale * dp, sd)
            g.add(wheels.fixed_scale_factor(X(k), X(k + 1), dR, verdict.scale * dp, sd))

    def gps_bias_nodes(self, k0: int, k1: int) -> np.ndarray:
        """The receiver-error nodes (one per fix, its index) of the fixes on keyframes [k0, k1)."""
        m = self.m
        if not (len(m.gps_k) and m.gps_bias_sigma_v > 0):
            return np.zeros(0, np.int64)
        return np.flatnonzero((m.gps_k >= k0) & (m.gps_k < k1))

    def _odom(self, g, k0: int, k1: int) -> None:
        """Absolute poses (``pose``: tied to the world at the first one by the filter's pose there, as the filter
        ties them) or increments (``delta``) of the odometry."""
        m, od = self.m, self.m.prep.odom
        if len(m.odom_k) and "pose" in m.prep.use["odom"]:
            T_world_odom = m.odom_world(self.s)
            for a in np.flatnonzero((m.odom_k >= k0) & (m.odom_k < k1)).tolist():
                i, k = int(m.odom_idx[a]), int(m.odom_k[a])
                ps = ODOM_POSE_SIGMA_SCALE * od.position_sigma_m[i]
                # beside the height prior, the odometry's height and tilt (they drift with its pitch) held less
                zs, ts = (1.0, 1.0) if self.level is None else (height.ODOM_VERTICAL_SIGMA_SCALE,
                                                                 height.ODOM_TILT_SIGMA_SCALE)
                rs = od.rotation_sigma_rad[i]
                sig = np.r_[rs * ts, rs * ts, rs, ps, ps, ps * zs]
                g.add(gtsam.PriorFactorPose3(X(k), gtsam.Pose3(T_world_odom @ od.poses[i]),
                                             gtsam.noiseModel.Diagonal.Sigmas(sig)))
            return
        for a in range(len(m.odom_k) - 1):
            ka, kb = int(m.odom_k[a]), int(m.odom_k[a + 1])
            if ka < k0 or kb >= k1 or ka == kb:
                continue
            i, j = int(m.odom_idx[a]), int(m.odom_idx[a + 1])
            T = np.linalg.inv(od.poses[i]) @ od.poses[j]
            rs = ODOM_DELTA_SHARE * float(np.hypot(od.rotation_sigma_rad[i], od.rotation_sigma_rad[j]))
            if m.odom_spin is not None:  # what the log shows they are worth, never looser than the sigmas say
                rs = min(rs, ODOM_SPIN_MARGIN * m.odom_spin)
            ps = ODOM_DELTA_SHARE * float(np.hypot(od.position_sigma_m[i], od.position_sigma_m[j]))
            noise = gtsam.noiseModel.Diagonal.Sigmas(np.r_[np.full(3, rs), np.full(3, ps)])
            g.add(gtsam.BetweenFactorPose3(X(ka), X(kb), gtsam.Pose3(T), noise))

    def _bridge(self, g, k: int) -> None:
        """No IMU across [k, k+1]: the filter's increment of pose and velocity, trusted like a motion model."""
        s = self.s
        dt = max((self.m.kt[k + 1] - self.m.kt[k]) * 1e-9, 1e-3)
        a, b = nav(s["R"][k], s["p"][k]), nav(s["R"][k + 1], s["p"][k + 1])
        ps, rs = BRIDGE_ACCEL_DENSITY * dt**1.5, BRIDGE_ROTATION_DENSITY * dt**0.5
        g.add(gtsam.BetweenFactorPose3(X(k), X(k + 1), a.between(b),
                                       gtsam.noiseModel.Diagonal.Sigmas(np.r_[np.full(3, rs), np.full(3, ps)])))
        g.add(gtsam.BetweenFactorVector(V(k), V(k + 1), s["v"][k + 1] - s["v"][k],
                                        gtsam.noiseModel.Isotropic.Sigma(3, BRIDGE_ACCEL_DENSITY * dt**0.5)))
        nz = self.m.noise
        bs = np.r_[np.full(3, nz.accel_bias_walk), np.full(3, nz.gyro_bias_walk)] * dt**0.5
        g.add(gtsam.BetweenFactorConstantBias(B(k), B(k + 1), gtsam.imuBias.ConstantBias(),
                                              gtsam.noiseModel.Diagonal.Sigmas(bs)))
        self.bridged += 1
