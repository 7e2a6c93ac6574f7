"""Gaps in the input (a mixin of ``LioOdometry``, ``core/odometry.py``).

A LiDAR gap (no scan for longer than ``max_gap_s``) that the IMU covers, while the IMU state runs, is bridged: the
state is propagated across it in scan-long steps, each corrected by the wheel speed where there are wheels, and the
first scan after it is registered from that prediction with kiss-icp's full iterations and a correspondence gate
widened by how far an IMU prediction drifts over that long (``bridge_gate_m``). A registration the prediction
cannot explain takes the usual recovery path (LiDAR-only, the IMU state started again). A gap longer than
``max_bridge_s``, one in which the IMU has a gap too, or one without an IMU state restarts from the LiDAR.

An IMU gap (no sample for longer than ``MAX_IMU_GAP_NS``, see ``imu_gap_ns``) within a scan's interval would
prime the scan with rates interpolated or held across it, wrong by many degrees at a walker's yaw swings: such a
scan is registered LiDAR-only from yaw hypotheses around constant velocity (each de-skewed by its own motion; the
best fit to the map wins), kept out of the map, and the IMU state is re-seeded from it (pose, mean velocity since
the gap began) keeping its biases and gravity. An IMU gap longer than ``max_gap_s`` drops the IMU state instead; it
starts again from LiDAR-only scans after the gap, as at start-up.
"""

from __future__ import annotations

import numpy as np

from ...geometry import so3_exp
from ...model.records import PointCloud
from ..imu import MAX_IMU_GAP_NS, imu_gap_ns, propagate
from ..kdtree import ckdtree_class

_BRIDGE_STEP_NS = 100_000_000  # the wheel speed corrects a bridged state this often (the last scan interval if known)
# How far an IMU prediction drifts over a gap of T: sigma_v T + sigma_a T^2 / 2, with the velocity and acceleration
# (tilt, accelerometer bias) errors of a converged state; the correspondence gate is the usual one plus 3 of those.
_DRIFT_SIGMA_MPS = 0.05
_DRIFT_SIGMA_MPS2 = 0.1
_GATE_M = 0.5  # the IMU prior's fixed gate
_MAX_BRIDGE_GATE_M = 2.0  # kiss-icp's initial adaptive threshold
# A scan over an IMU gap has no rotation prior better than constant velocity, which is off by 15-20 deg per scan at a
# walker's yaw swings, beyond ICP's reach: it is registered from yaw hypotheses around it and the best fit is kept.
_BLIND_YAWS_RAD = np.radians([0.0, 8.0, -8.0, 16.0, -16.0, 24.0, -24.0])
_BLIND_GATE_M = 1.0
_RESEED_SIGMA_RAD = 0.05  # the state re-seeded from such a scan: its pose and velocity are this uncertain
_RESEED_SIGMA_M = 0.1
_RESEED_SIGMA_MPS = 0.5


def bridge_gate_m(gap_s: float) -> float:
    """Correspondence gate of the first scan after a bridged gap of ``gap_s``."""
    drift_m = _DRIFT_SIGMA_MPS * gap_s + 0.5 * _DRIFT_SIGMA_MPS2 * gap_s**2
    return float(min(_GATE_M + 3.0 * drift_m, _MAX_BRIDGE_GATE_M))


class Gaps:
    """Bridging LiDAR gaps with the IMU state; LiDAR-only scans over IMU gaps."""

    def _bridge_refused(self, t_prev: int, t_ref: int) -> str | None:
        """Why a time gap cannot be bridged (words for the event), or None if it can."""
        if not self.imu_mode:
            return "no IMU state to carry across it"
        if (t_ref - t_prev) * 1e-9 > self.cfg.max_bridge_s:
            return f"longer than max_bridge_s, {self.cfg.max_bridge_s:g} s"
        cost_ns, hole_ns = imu_gap_ns(self._imu_window(t_prev).stamps_ns, t_prev, t_ref)
        if cost_ns > MAX_IMU_GAP_NS:
            return f"the IMU has a {hole_ns * 1e-9:.3g} s gap in it too"
        return None

    def _bridge(self, cloud: PointCloud, t_prev: int, t_ref: int):  # -> ScanResult | None
        """Carry the IMU state across a time gap, then register the scan after it from the prediction."""
        step_ns = int(self._last_dt_s * 1e9) if self._last_dt_s > 0 else _BRIDGE_STEP_NS
        t_last = max(t_prev, t_ref - step_ns)  # the scan's own interval is the IMU step's
        imu = self._imu_window(t_prev)
        noise = self._imu_noise
        saved, t, wheel_updates = self.state, t_prev, self.stats.wheel_updates
        while t < t_last:
            t_next = min(t + step_ns, t_last)
            self.state = propagate(self.state, imu, t_next, self.ext, noise=noise, planar=self.planar).state
            self._wheel_update(t, t_next)
            t = t_next
        predicted = propagate(self.state, imu, t_ref, self.ext, planar=self.planar).state.p
        if self.clock is not None:
            self.clock.reset()  # its window of rates has a hole
        gap_s = (t_ref - t_prev) * 1e-9
        event = self._event("time gap", f"{gap_s:.3g} s without a scan: bridged by the IMU state"
                                        f"{' and wheel speed' if self.stats.wheel_updates > wheel_updates else ''}")
        recoveries = self.stats.recoveries
        res = self._imu_step(cloud, t_last, t_ref, bridge_gate_m=bridge_gate_m(gap_s))
        if res is None:  # the scan was skipped: the next one bridges the gap again from where it began
            self.state = saved
            event["reason"] += "; the scan after it was skipped"
        elif not res.failed and self.stats.recoveries == recoveries:
            moved = float(np.linalg.norm(res.pose[:3, 3] - predicted))
            event["reason"] += f"; the scan after it registered {moved:.2f} m from the prediction"
        return res

    def _imu_hole(self, t_prev: int, t_ref: int) -> bool:
        """The scan's interval has an IMU gap (counted) where the IMU would otherwise prime it."""
        if not (self.use_imu and self.imu_mounted and self._imu):
            return False
        stamps = self._imu_window(t_prev).stamps_ns
        if not len(stamps) or stamps[0] > t_prev:
            return False  # before the IMU starts: no gap, nothing to prime with (a gap's end is not known online)
        hole = imu_gap_ns(stamps, t_prev, t_ref)[0] > MAX_IMU_GAP_NS
        self.stats.imu_gaps += int(hole)
        return hole

    def _imu_gap_step(self, cloud: PointCloud, t_prev: int, t_ref: int, hole_ns: int):  # -> ScanResult | None
        """An IMU-mode scan over an IMU gap: registered LiDAR-only and kept out of the map (it is a few degrees off);
        the IMU state is re-seeded from it (its pose, the mean velocity since the gap began, their covariance
        widened) and keeps its biases and gravity, so the first scan after the gap is IMU-primed again."""
        kept, g_world = self.state, self._g_world
        if self._imu_gap_from is None:  # the gap's first scan: (last pose before it, its stamp, its event)
            event = self._event("imu gap", f"no IMU sample for {hole_ns * 1e-9:.3g} s")
            self._imu_gap_from = (self._last_pose, self._last_ns, event)
        gap_from = self._imu_gap_from
        pose0, t0, event = gap_from
        self._lose_imu_state()  # for _lidar_step: LiDAR-only; the gap's start is kept
        self._imu_gap_from = gap_from
        if t0 is not None and (t_ref - t0) * 1e-9 > self.cfg.max_gap_s:  # too long to leave out of the map
            self._imu_gap_from = None
            event["reason"] += f"; after {(t_ref - t0) * 1e-9:.3g} s the IMU state starts again from LiDAR-only scans"
            return self._lidar_step(cloud, t_prev, t_ref)
        res = self._lidar_step(cloud, t_prev, t_ref, window=False, mapped=False)
        self._g_world = g_world
        if res is None:  # skipped: the state stays where the last scan left it
            self.state = kept
            return None
        s = kept.copy()
        s.stamp_ns, s.R, s.p = t_ref, res.pose[:3, :3].copy(), res.pose[:3, 3].copy()
        if not res.failed and t0 is not None and t_ref > t0:
            s.v = (res.pose[:3, 3] - pose0[:3, 3]) / ((t_ref - t0) * 1e-9)
        s.P[0:9, :] = 0.0
        s.P[:, 0:9] = 0.0
        s.P[0:9, 0:9] = np.diag([_RESEED_SIGMA_RAD**2] * 3 + [_RESEED_SIGMA_M**2] * 3 + [_RESEED_SIGMA_MPS**2] * 3)
        self.state = s
        scans = self.stats.scans - event["scan"] + 1
        event["reason"] = (f"no IMU sample for {hole_ns * 1e-9:.3g} s: {scans} scan{'s' * (scans > 1)} registered "
                           "LiDAR-only (yaw hypotheses around constant velocity), kept out of the map; the IMU state "
                           "re-seeded from them")
        return res

    def _register_blind(self, cloud: PointCloud, t_prev: int, t_ref: int, guess: np.ndarray):
        """(points, map frame, pose) of a scan without a rotation prior, or None if too few points: from yaw
        hypotheses about the world's up axis around ``guess``, each de-skewed by the motion it implies and again
        by the motion registered from it; the one whose points lie closest to the map (distances truncated at a
        voxel) is kept."""
        reg = self._reg
        up = np.array([0.0, 0.0, 1.0]) if self._g_world is None else -self._g_world / np.linalg.norm(self._g_world)
        if self._blind_tree is None or self._blind_tree[:2] != (reg, reg.scans):  # the map grew or restarted
            self._blind_tree = (reg, reg.scans, ckdtree_class()(reg.map.point_cloud()))  # (map, its scans, tree)
        tree = self._blind_tree[2]  # the scans of one IMU gap stay out of the map: one tree serves them all
        best, best_cost = None, np.inf
        for yaw in _BLIND_YAWS_RAD:
            pose = guess.copy()
            pose[:3, :3] = so3_exp(up * yaw) @ guess[:3, :3]
            for _ in range(2):  # de-skewed by the hypothesis' motion, then by the registered one
                points = self._prepare(cloud, *self._cv_knots(pose, t_prev, t_ref), t_ref)
                if points is None:
                    return None
                frame, source = reg.downsample(points)
                pose = reg.register(source, pose, adaptive=True, gate_m=_BLIND_GATE_M)
                if not np.isfinite(pose).all():
                    break
            else:
                d, _ = tree.query(source @ pose[:3, :3].T + pose[:3, 3], distance_upper_bound=reg.voxel_size_m)
                cost = float(np.mean(np.minimum(d, reg.voxel_size_m) ** 2))
                if cost < best_cost:
                    best, best_cost = (points, frame, pose), cost
        return best if best is not None else (points, frame, pose)
