"""IMU-primed scan matching: the lecture's LIO pipeline on kiss-icp's registration and voxel map.

Per scan in IMU mode: propagate the IMU state to the scan's reference instant (its end by default), de-skew
every point with the propagated pose at its own stamp, register the de-skewed scan to the local map starting
from the IMU prediction, check the geometry for degenerate directions, then correct the state (EKF or
complementary filter) so the corrected velocity and biases prime the next scan.

The IMU state is never assumed: the first scans are registered LiDAR-only (gyro rotation, constant-velocity
translation) until ``init_window_s`` of poses can be aligned with the IMU (``bootstrap``: standing or moving
start). The same happens after a lost track: a registration the prediction cannot explain, a state that is
no longer plausible, or a persistent disagreement between prediction and registration sends the odometry
back to LiDAR-only scans, from which the IMU state is started again. The internal world frame is the first
scan's base frame; ``output_alignment`` levels it by the gravity found.

``LioOdometry`` is assembled from mixins: the LiDAR-only step in ``odometry_lidar``, the state updates and
guards in ``odometry_updates``, the start and restart of the IMU state in ``odometry_restart``, LiDAR gaps
bridged by the IMU state and scans over IMU gaps in ``odometry_gaps``.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field

import numpy as np

from ..config.odom import OdomConfig
from ..geometry import gravity_aligned_rotation, inv_pose, project_to_se2, row_norms
from ..model.calibration import Extrinsics
from ..model.records import ImuBatch, OdometryRecord, PointCloud
from .bootstrap import Bootstrap
from .clock_offset import ClockOffsetTracker
from .degeneracy import CLEAR_MARGIN, analyse_degeneracy
from .imu import MAX_IMU_GAP_NS, NavState, gravity_vector, imu_gap_ns, propagate
from .motion_compensation import constant_velocity_knots, deskew, to_base
from .odometry_gaps import Gaps
from .odometry_lidar import Diverged, LidarSteps, ScanResult
from .odometry_restart import Restart, WindowScan
from .odometry_updates import StateUpdates
from .registration import ScanRegistration, auto_voxel_size

_MIN_VELOCITY_DT_S = 0.02  # a constant-velocity prior needs at least this long an interval between poses
_WHEEL_KEEP_NS = 1_000_000_000  # wheel records older than this behind the last scan are dropped
_IMU_PRIOR_CORRESPONDENCE_M = 0.5


@dataclass
class OdomStats:
    scans: int = 0
    used: int = 0
    skipped_few_points: int = 0
    skipped_out_of_order: int = 0
    registration_failures: int = 0
    degenerate: int = 0
    imu_gaps: int = 0
    wheel_updates: int = 0
    wheel_zero_skipped: int = 0
    lidar_only_scans: int = 0  # registered without the IMU state: start-up window, recoveries, no IMU
    capped_icp_scans: int = 0  # IMU-primed scans registered with steady_ or slow_iterations
    predicted_scans: int = 0  # slowly turning scans whose pose is the IMU prediction, unregistered (slow_register_every)
    recoveries: int = 0
    time_gaps: int = 0
    times_s: dict[str, float] = field(default_factory=lambda: {"propagate": 0.0, "deskew": 0.0, "register": 0.0,
                                                               "degeneracy": 0.0, "fuse": 0.0})

    def counts(self) -> dict[str, int]:
        """Every counter (not the times), for metrics."""
        counts = {k: v for k, v in vars(self).items() if k not in ("scans", "times_s")}
        return {"total": self.scans, **counts}

class LioOdometry(StateUpdates, Restart, LidarSteps, Gaps):
    """Feed IMU batches, wheel records and scans (in time order); get one pose per scan."""

    def __init__(self, cfg: OdomConfig, T_base_lidar: np.ndarray, *, use_imu: bool, planar: bool,
                 gyro_bias: np.ndarray | None = None, accel_bias: np.ndarray | None = None,
                 gyro_only: bool = False) -> None:
        """``gyro_only``: every scan is registered LiDAR-only, primed and de-skewed by the gyro's rotation (once
        the IMU is mounted) but never fused with an IMU state: the poses are the registration's own."""
        self.cfg = cfg
        self.gyro_only = gyro_only
        self.ext = Extrinsics(np.eye(4), T_base_lidar)
        self.use_imu = use_imu
        self.planar = planar
        self.stats = OdomStats()
        self.start: Bootstrap | None = None
        self.events: list[dict] = []  # recoveries and time gaps: scan, time, reason
        self.state: NavState | None = None
        self.imu_mounted = False  # T_base_imu is known (set when the first IMU message names its frame)
        self._imu: list[ImuBatch] = []
        self._wheel: list[OdometryRecord] = []
        self._reg: ScanRegistration | None = None
        self._last_pose = np.eye(4)
        self._last_delta = np.eye(4)
        self._last_ns: int | None = None
        self._last_dt_s = 0.0
        self._imu_prior = use_imu and cfg.prior == "imu"
        self._deskew = cfg.resolved_deskew()
        self._bias_prior = (gyro_bias, accel_bias)  # from a calibration file, if any
        self._dirs_b: list[np.ndarray] = []  # degenerate directions of the last analysed scan (its base frame)
        # (no analysis before this many scans are used, the scan analysed last): a clear scene is analysed less
        # often, and a scan registered again (a retry) analysed again; reset with the map
        self._degeneracy_due = (0, -1)
        self._predicted_run = 0  # slowly turning scans given their IMU prediction since the last registered one
        self.predicted_ns: set[int] = set()  # the stamps of those scans (their poses are not registered ones)
        self._g_world: np.ndarray | None = gravity_vector(cfg.gravity_mps2) if planar else None
        self._window: list[WindowScan] = []  # LiDAR-only scans that will start the IMU state
        self.stamps_ns: list[int] = []  # the trajectory so far (internal world frame); the start-up window's
        self.poses: list[np.ndarray] = []  # LiDAR-only poses are replaced once the IMU state starts
        self._first_f_base: np.ndarray | None = None  # mean specific force (base axes) around the first scan
        self._lost = 0  # LiDAR-only registrations failed in a row
        self._map_restarts = 0
        self.clock: ClockOffsetTracker | None = None  # online IMU-LiDAR time offset (once the IMU is mounted)
        self._shift_ns = 0  # correction added to IMU stamps, as the clock tracker found it
        self._doubt = 0  # IMU-mode scans in a row whose innovation was implausible
        self._imu_gap_from: tuple | None = None  # (pose, stamp, event) before an IMU gap the scans are in
        self._blind_tree: tuple | None = None  # (map, its scans, its k-d tree) for scans over an IMU gap

    # ---- inputs -------------------------------------------------------------------------------
    def set_imu_extrinsic(self, T_base_imu: np.ndarray) -> None:
        self.ext = Extrinsics(np.asarray(T_base_imu, dtype=np.float64), self.ext.T_base_lidar)
        self.imu_mounted = True
        if self.cfg.estimate_time_offset and not self.planar:
            self.clock = ClockOffsetTracker()

    def add_imu(self, batch: ImuBatch) -> None:
        if self._shift_ns:
            batch = ImuBatch(batch.frame_id, batch.stamps_ns + self._shift_ns, batch.gyro_radps, batch.accel_mps2)
        self._imu.append(batch)
        if self.clock is not None:
            self.clock.add_imu(batch.stamps_ns, batch.gyro_radps)

    def close_clock(self) -> None:
        """The clock tracker's closing estimate, once every scan is done (see ``ClockOffsetTracker.close``)."""
        if self.clock is not None and self.state is not None:
            self.clock.close(self.state.bg, self.stats.scans)

    def _shift_imu(self, delta_ns: int) -> None:
        """Move every IMU sample, buffered and to come, by ``delta_ns`` onto the LiDAR's clock."""
        self._shift_ns += delta_ns
        self._imu = [ImuBatch(b.frame_id, b.stamps_ns + delta_ns, b.gyro_radps, b.accel_mps2) for b in self._imu]
        self._event("clock offset", f"IMU stamps moved by {delta_ns * 1e-6:+.2f} ms onto the LiDAR's clock "
                                    f"(estimated online; {self._shift_ns * 1e-6:+.2f} ms in all)")

    def add_wheel(self, rec: OdometryRecord) -> None:
        self._wheel.append(rec)

    def imu_until_ns(self) -> int | None:
        return int(self._imu[-1].stamps_ns[-1]) if self._imu else None

    @property
    def voxel_size_m(self) -> float | None:
        """The map's voxel size, once the first scan has set it."""
        return self._reg.voxel_size_m if self._reg is not None else None

    @property
    def imu_mode(self) -> bool:
        return self.state is not None

    @property
    def imu_shift_ns(self) -> int:
        """What the online clock tracker has added to the IMU stamps so far (beyond the calibration's offset)."""
        return self._shift_ns

    @property
    def settled(self) -> int:
        """How many leading poses can no longer change: all but the start-up window's, which are replaced
        when the IMU state starts from them."""
        return self._window[0].out_index if self._window else len(self.poses)

    def _imu_window(self, t0_ns: int) -> ImuBatch:
        """IMU samples from just before ``t0_ns`` on; older batches are dropped (bounded memory).

        The start-up window's samples are kept until the window is aligned."""
        if self._window:
            t0_ns = min(t0_ns, self._window[0].t_prev_ns)
        imu = ImuBatch.concat(self._imu)
        if len(imu):
            keep = max(0, int(np.searchsorted(imu.stamps_ns, t0_ns)) - 2)
            imu = ImuBatch(imu.frame_id, imu.stamps_ns[keep:], imu.gyro_radps[keep:], imu.accel_mps2[keep:])
        self._imu = [imu] if len(imu) else []
        return imu

    def output_alignment(self) -> np.ndarray:
        """T_out_world: levels the internal world frame (the first scan's base) by the gravity found."""
        T = np.eye(4)
        if self._g_world is not None:  # gravity as the last healthy IMU state (or the start-up) had it
            T[:3, :3] = gravity_aligned_rotation(-self._g_world)
        elif self._first_f_base is not None:  # never aligned: "up" is the specific force at the first scan
            T[:3, :3] = gravity_aligned_rotation(self._first_f_base)
        return T

    # ---- one scan -----------------------------------------------------------------------------
    def process(self, cloud: PointCloud) -> ScanResult | None:
        cfg, st = self.cfg, self.stats
        st.scans += 1
        if len(cloud.points) < cfg.registration.min_points:
            st.skipped_few_points += 1
            return None
        t_ref = cloud.end_ns if cfg.scan_reference == "end" else cloud.start_ns
        if self._last_ns is not None and t_ref <= self._last_ns:
            st.skipped_out_of_order += 1  # a scan ending before the previous one cannot be placed
            return None
        t_prev = cloud.start_ns if self._last_ns is None else self._last_ns
        if (t_ref - t_prev) * 1e-9 > cfg.max_gap_s:  # bridged by the IMU state if it can, else restart
            st.time_gaps += 1
            refused = self._bridge_refused(t_prev, t_ref)
            if refused is None:
                return self._bridge(cloud, t_prev, t_ref)
            self._event("time gap", f"{(t_ref - t_prev) * 1e-9:.3g} s without a scan ({refused}): restarted from "
                                    "the LiDAR")
            self._lose_imu_state()
            self._last_delta = np.eye(4)
            t_prev = cloud.start_ns
        if self.imu_mode:
            return self._imu_step(cloud, t_prev, t_ref)
        return self._lidar_step(cloud, t_prev, t_ref)

    @property
    def _imu_noise(self):
        """The IMU noise propagation carries (the EKF's), or None (the complementary filter keeps no covariance)."""
        return self.cfg.fusion.imu if self.cfg.fusion.method == "ekf" else None

    def _event(self, kind: str, reason: str) -> dict:
        """Record an event (and return it: a gap's reason is completed as its scans come)."""
        event = {"kind": kind, "scan": self.stats.scans, "after_stamp_ns": self._last_ns, "reason": reason}
        self.events.append(event)
        return event

    def _lose_imu_state(self) -> None:
        self.state = None  # gravity survives in _g_world, as the last healthy state had it
        if self.clock is not None:
            self.clock.reset()
        self._window = []
        self._doubt = 0
        self._imu_gap_from = None  # a restart ends any IMU gap the scans were in

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
            every = fc.degeneracy_every_clear if found.margin >= CLEAR_MARGIN else fc.degeneracy_every
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
        dt_scan = (t_ref - t_prev) * 1e-9
        if self._deskew == "imu":
            knots, knot_poses = prop.stamps_ns, prop.poses
        elif self._deskew == "constant-velocity":
            knots, rel = constant_velocity_knots(self._last_delta, t_prev, t_ref)
            knot_poses = self._last_pose[None] @ rel
        else:
            knots = knot_poses = None
        slow = bridge_gate_m is None and self._turning_slowly(imu, t_prev, t_ref)  # a bridge: full iterations
        if self._predicted_only(slow):
            result = self._finish(t_ref, self.state.pose(), None, None, [], False)
            self.predicted_ns.add(t_ref)
            return result
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


__all__ = ["Diverged", "LioOdometry", "ScanResult", "OdomStats"]
