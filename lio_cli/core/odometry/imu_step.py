"""The IMU-primed scan step of ``LioOdometry`` (``core/odometry.py``) and what every scan step shares: the
de-skewed points in range, the degeneracy check on its schedule, and the pose's bookkeeping.

A mixin, split out to keep each module readable; it uses the odometry's attributes (``cfg``, ``state``,
``stats``, ``ext``, ``planar``, ``_reg``, ``_wheel`` ...) and the other mixins' methods.
"""

from __future__ import annotations

import time

import numpy as np

from ...geometry import inv_pose, project_to_se2, row_norms
from ...model.records import PointCloud
from .degeneracy import CLEAR_MARGIN, analyse_degeneracy
from ..imu import MAX_IMU_GAP_NS, imu_gap_ns, propagate
from ..motion_compensation import constant_velocity_knots, deskew, to_base
from .lidar_step import ScanResult
from .registration import ScanRegistration, auto_voxel_size

_MIN_VELOCITY_DT_S = 0.02  # a constant-velocity prior needs at least this long an interval between poses
_WHEEL_KEEP_NS = 1_000_000_000  # wheel records older than this behind the last scan are dropped
_IMU_PRIOR_CORRESPONDENCE_M = 0.5


class ScanSteps:
    """The IMU-primed step of ``LioOdometry`` and the parts every step shares."""

    def _prepare(self, cloud: PointCloud, knots_ns, knot_poses, t_ref: int) -> np.ndarray | None:
        """De-skewed points in the base frame at ``t_ref`` within the range limits, or None if too few."""
        cfg = self.cfg
        tick = time.perf_counter()
        if knots_ns is None:
            points = to_base(cloud.points, self.ext.T_base_lidar)
        else:
            points = deskew(cloud.points, cloud.point_stamps_ns, knots_ns, knot_poses, t_ref, self.ext.T_base_lidar)
        rng = row_norms(points)
        keep = (rng >= cfg.registration.min_range_m) & (rng <= cfg.registration.max_range_m)
        self.stats.times_s["deskew"] += time.perf_counter() - tick
        kept = int(np.count_nonzero(keep))
        if kept < cfg.registration.min_points:
            self.stats.skipped_few_points += 1
            return None
        if self._reg is None:
            fixed = cfg.registration.max_correspondence_m
            if fixed is None and self._imu_prior:
                fixed = _IMU_PRIOR_CORRESPONDENCE_M
            self._reg = ScanRegistration(cfg.registration, cfg.registration.voxel_size_m or auto_voxel_size(rng[keep]),
                                         imu_prior=self._imu_prior, planar=self.planar, fixed_correspondence_m=fixed)
        return points if kept == len(points) else points[keep]  # all in range, as most scans: no copy

    def _degeneracy(self, points: np.ndarray, R_now: np.ndarray) -> list[np.ndarray]:
        tick = time.perf_counter()
        fc = self.cfg.fusion
        if self._reg.empty:
            dirs_b = []
        elif self.stats.used % fc.degeneracy_every == 0 and (self.stats.used >= self._degeneracy_due[0]
                                                            or self.stats.used == self._degeneracy_due[1]):
            # geometry changes little between scans; far from degenerate, it is looked at again later. The scan
            # analysed last is analysed again when it is registered again (a retry): its reuse would turn it
            found = analyse_degeneracy(points, self.planar, fc.degeneracy_ratio)
            dirs_b = self._dirs_b = found.directions
            self._clear_scene = found.margin >= CLEAR_MARGIN
            every = fc.degeneracy_every_clear if self._clear_scene else fc.degeneracy_every
            self._degeneracy_due = (self.stats.used + every, self.stats.used)
        else:
            dirs_b = [R_now.T @ self._last_pose[:3, :3] @ d for d in self._dirs_b]
        self.stats.times_s["degeneracy"] += time.perf_counter() - tick
        return dirs_b

    def _finish(self, t_ref: int, pose: np.ndarray, frame: np.ndarray | None, correction: np.ndarray | None,
                dirs_b: list, failed: bool) -> ScanResult:
        """Record the scan's pose; ``frame`` (None for a failed scan, which stays out of the map) joins the map."""
        st = self.stats
        self.predicted_ns.discard(t_ref)  # a scan registered again (a replay)
        if frame is not None:
            self._reg.accept(correction, frame, pose)
        delta = inv_pose(self._last_pose) @ pose
        dt_s = (t_ref - self._last_ns) * 1e-9 if self._last_ns is not None else 0.0
        if 0.0 < dt_s < _MIN_VELOCITY_DT_S:
            # two scan references this close (a scan whose points all carry one stamp) cannot give a velocity:
            # the interval is extended back over the previous one (if any) instead of dividing by a millisecond
            delta, dt_s = (self._last_delta @ delta, dt_s + self._last_dt_s) if self._last_dt_s > 0.0 else (np.eye(4), 0.0)
        self._last_delta, self._last_dt_s = delta, dt_s
        self._last_pose = pose
        self._last_ns = t_ref
        keep_from = self._window[0].t_prev_ns if self._window else t_ref
        self._wheel = [w for w in self._wheel if w.stamp_ns > keep_from - _WHEEL_KEEP_NS]  # bounded memory
        st.degenerate += int(bool(dirs_b))
        st.used += 1
        self.stamps_ns.append(t_ref)
        self.poses.append(pose)
        return ScanResult(t_ref, pose, bool(dirs_b), failed)

    # ---- IMU-primed -----------------------------------------------------------------------------
    def _imu_step(self, cloud: PointCloud, t_prev: int, t_ref: int,
                  bridge_gate_m: float | None = None) -> ScanResult | None:
        """``bridge_gate_m``: the first scan after a bridged time gap, registered with this gate and full iterations."""
        st = self.stats
        tick = time.perf_counter()
        imu = self._imu_window(t_prev)
        cost_ns, hole_ns = imu_gap_ns(imu.stamps_ns, t_prev, t_ref)
        if cost_ns > MAX_IMU_GAP_NS:  # rates interpolated or held across it would prime the scan wrongly
            return self._imu_gap_step(cloud, t_prev, t_ref, hole_ns)
        self._imu_gap_from = None
        prop = propagate(self.state, imu, t_ref, self.ext,
                         noise=self._imu_noise, planar=self.planar)
        st.imu_gaps += int(prop.gap)
        saved = self.state
        self.state = prop.state
        self._wheel_update(t_prev, t_ref)
        st.times_s["propagate"] += time.perf_counter() - tick
        slow = bridge_gate_m is None and self._turning_slowly(imu, t_prev, t_ref)  # a bridge: full iterations
        if self._predicted_only(slow):
            result = self._finish(t_ref, self.state.pose(), None, None, [], False)
            self.predicted_ns.add(t_ref)
            return result
        dt_scan = (t_ref - t_prev) * 1e-9
        if self._deskew == "imu":
            knots, knot_poses = prop.stamps_ns, prop.poses
        elif self._deskew == "constant-velocity":
            knots, rel = constant_velocity_knots(self._last_delta, t_prev, t_ref)
            knot_poses = self._last_pose[None] @ rel
        else:
            knots = knot_poses = None
        points = self._prepare(cloud, knots, knot_poses, t_ref)
        if points is None:
            self.state = saved  # the scan is skipped: keep the state where the last used scan left it
            return None
        tick = time.perf_counter()
        guess = self._guess(t_prev, t_ref)
        frame, source = self._reg.downsample(points)
        cap = None if bridge_gate_m is not None else self._icp_cap(slow)
        st.capped_icp_scans += int(cap is not None)
        measured = self._reg.register(source, guess, adaptive=bridge_gate_m is not None, gate_m=bridge_gate_m,
                                      iterations=cap)
        st.times_s["register"] += time.perf_counter() - tick
        dirs_b = self._degeneracy(points, self.state.R)
        if self.planar:
            measured = project_to_se2(measured)
        failed = self._registration_failed(measured, guess, bridge_gate_m)
        if failed:
            st.registration_failures += 1
            # the prediction cannot explain the scan: if the LiDAR alone can, the state is suspect and starts
            # again from LiDAR-only scans; if it cannot either, the scan is bad and the prediction stands
            kept, g_world = self.state, self._g_world
            self._lose_imu_state()
            res = self._lidar_step(cloud, t_prev, t_ref, retry=True)
            if res is not None:
                st.recoveries += 1
                self._event("recovery", "the IMU prediction could not explain the scan (registration "
                                        f"{np.linalg.norm(measured[:3, 3] - guess[:3, 3]):.2f} m from it or without "
                                        "correspondences), LiDAR-only registration could: back to LiDAR-only scans")
                return res
            self.state, self._g_world = kept, g_world
            self._count_lost(t_ref)
            return self._finish(t_ref, self.state.pose(), None, None, dirs_b, True)
        tick = time.perf_counter()
        reason = self._implausible(measured, dirs_b)
        if self._doubt:  # the innovation is not believable: follow the LiDAR, keep velocity, biases and gravity
            st.times_s["fuse"] += time.perf_counter() - tick
            return self._doubted_scan(cloud, t_prev, t_ref, measured, guess, frame, dirs_b, reason)
        else:
            pose = self._correct(measured, dirs_b, dt_scan)
            reason = reason or self._state_implausible()
            if reason is None:
                self._g_world = self.state.g.copy()  # the latest gravity of a healthy state
                if cap is None:  # a capped registration leans on the IMU's timing: it cannot time it
                    self._track_clock(t_ref, measured)
        st.times_s["fuse"] += time.perf_counter() - tick
        self._lost = 0
        result = self._finish(t_ref, pose, frame, inv_pose(guess) @ measured, dirs_b, False)
        if reason is not None:
            st.recoveries += 1
            self._event("recovery", reason + ": back to LiDAR-only scans")
            self._lose_imu_state()
        return result


__all__ = ["ScanSteps"]
