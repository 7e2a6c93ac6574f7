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
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field

import numpy as np

from ..config.odom import OdomConfig
from ..errors import ProcessingError
from ..geometry import gravity_aligned_rotation, inv_pose, project_to_se2, so3_exp, so3_log
from ..model.calibration import Extrinsics
from ..model.records import ImuBatch, OdometryRecord, PointCloud
from .bootstrap import Bootstrap, align
from .clock_offset import ClockOffsetTracker
from .degeneracy import degenerate_directions
from .filter import (complementary_update, complementary_velocity_update, ekf_body_velocity_update, ekf_pose_update,
                     pose_innovation_nis, position_noise)
from .imu import NavState, flatten_planar, gravity_vector, propagate
from .motion_compensation import constant_velocity_knots, deskew, to_base
from .registration import ScanRegistration, auto_voxel_size
from .wheel import mean_twist, planar_delta

_MAX_JUMP_M = 1.0  # a registration this far from the IMU prediction within one scan is treated as failed
_MAX_JUMP_RAD = 0.35
_WHEEL_KEEP_NS = 1_000_000_000  # wheel records older than this behind the last scan are dropped
_IMU_PRIOR_CORRESPONDENCE_M = 0.5
_GYRO_PRIOR_GATE_M = 1.0  # LiDAR-only scans with the gyro's rotation: the translation guess is constant velocity
_GYRO_PRIOR_JUMP_M = 2.0  # ...so a registration this far from it (or turned this much) has failed
_GYRO_PRIOR_JUMP_RAD = np.radians(10.0)
_NIS_LIMIT = 100.0  # a pose innovation this far outside its covariance (chi-square 6 dof: 22 at 99.9 %; a 15 ms IMU
# clock offset on fast yaw sweeps reaches 80)...
_NIS_SCANS = 3  # ...this many scans in a row means the IMU state no longer explains the scans
_MOVING_MPS = 0.3  # faster than this, an exactly-zero wheel twist is not a wheel at rest
_MOVING_M = 0.3
_MAX_BIAS_GYRO_RADPS = 0.5
_MAX_BIAS_ACCEL_MPS2 = 3.0


class Diverged(ProcessingError):
    """The track is lost for good: LiDAR-only registration failed for ``max_lost_scans`` scans in a row."""


@dataclass
class ScanResult:
    stamp_ns: int  # the reference instant the scan was de-skewed to
    pose: np.ndarray  # T_world_base after correction (internal world frame)
    degenerate: bool
    failed: bool


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
    recoveries: int = 0
    time_gaps: int = 0
    times_s: dict[str, float] = field(default_factory=lambda: {"propagate": 0.0, "deskew": 0.0, "register": 0.0,
                                                               "degeneracy": 0.0, "fuse": 0.0})

    def counts(self) -> dict[str, int]:
        """Every counter (not the times), for metrics."""
        counts = {k: v for k, v in vars(self).items() if k not in ("scans", "times_s")}
        return {"total": self.scans, **counts}


class LioOdometry:
    """Feed IMU batches, wheel records and scans (in time order); get one pose per scan."""

    def __init__(self, cfg: OdomConfig, T_base_lidar: np.ndarray, *, use_imu: bool, planar: bool,
                 gyro_bias: np.ndarray | None = None, accel_bias: np.ndarray | None = None) -> None:
        self.cfg = cfg
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
        self._g_world: np.ndarray | None = gravity_vector(cfg.gravity_mps2) if planar else None
        self._window: list[_WindowScan] = []  # LiDAR-only scans that will start the IMU state
        self.stamps_ns: list[int] = []  # the trajectory so far (internal world frame); the start-up window's
        self.poses: list[np.ndarray] = []  # LiDAR-only poses are replaced once the IMU state starts
        self._first_f_base: np.ndarray | None = None  # mean specific force (base axes) around the first scan
        self._lost = 0  # LiDAR-only registrations failed in a row
        self.clock: ClockOffsetTracker | None = None  # online IMU-LiDAR time offset (once the IMU is mounted)
        self._shift_ns = 0  # correction added to IMU stamps, as the clock tracker found it
        self._doubt = 0  # IMU-mode scans in a row whose innovation was implausible

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
        if (t_ref - t_prev) * 1e-9 > cfg.max_gap_s:  # a gap is a gap: restart from the LiDAR, never integrate
            st.time_gaps += 1
            self._event("time gap", f"{(t_ref - t_prev) * 1e-9:.3g} s without a scan: restarted from the LiDAR")
            self._lose_imu_state()
            self._last_delta = np.eye(4)
            t_prev = cloud.start_ns
        if self.imu_mode:
            return self._imu_step(cloud, t_prev, t_ref)
        return self._lidar_step(cloud, t_prev, t_ref)

    def _event(self, kind: str, reason: str) -> None:
        t = None if self._last_ns is None else self._last_ns
        self.events.append({"kind": kind, "scan": self.stats.scans, "after_stamp_ns": t, "reason": reason})

    def _lose_imu_state(self) -> None:
        self.state = None  # gravity survives in _g_world, as the last healthy state had it
        if self.clock is not None:
            self.clock.reset()
        self._window = []
        self._doubt = 0

    def _prepare(self, cloud: PointCloud, knots_ns, knot_poses, t_ref: int) -> np.ndarray | None:
        """De-skewed points in the base frame at ``t_ref`` within the range limits, or None if too few."""
        cfg = self.cfg
        tick = time.perf_counter()
        if knots_ns is None:
            points = to_base(cloud.points, self.ext.T_base_lidar)
        else:
            points = deskew(cloud.points, cloud.point_stamps_ns, knots_ns, knot_poses, t_ref, self.ext.T_base_lidar)
        rng = np.linalg.norm(points, axis=1)
        keep = (rng >= cfg.registration.min_range_m) & (rng <= cfg.registration.max_range_m)
        self.stats.times_s["deskew"] += time.perf_counter() - tick
        if keep.sum() < cfg.registration.min_points:
            self.stats.skipped_few_points += 1
            return None
        if self._reg is None:
            fixed = cfg.registration.max_correspondence_m
            if fixed is None and self._imu_prior:
                fixed = _IMU_PRIOR_CORRESPONDENCE_M
            self._reg = ScanRegistration(cfg.registration, cfg.registration.voxel_size_m or auto_voxel_size(rng[keep]),
                                         imu_prior=self._imu_prior, planar=self.planar, fixed_correspondence_m=fixed)
        return points[keep]

    def _degeneracy(self, points: np.ndarray, R_now: np.ndarray) -> list[np.ndarray]:
        tick = time.perf_counter()
        if self._reg.empty:
            dirs_b = []
        elif self.stats.used % self.cfg.fusion.degeneracy_every == 0:  # geometry changes little between scans
            dirs_b = self._dirs_b = degenerate_directions(points, self.planar, self.cfg.fusion.degeneracy_ratio)
        else:
            dirs_b = [R_now.T @ self._last_pose[:3, :3] @ d for d in self._dirs_b]
        self.stats.times_s["degeneracy"] += time.perf_counter() - tick
        return dirs_b

    def _finish(self, t_ref: int, pose: np.ndarray, frame: np.ndarray | None, correction: np.ndarray | None,
                dirs_b: list, failed: bool) -> ScanResult:
        """Record the scan's pose; ``frame`` (None for a failed scan, which stays out of the map) joins the map."""
        st = self.stats
        if frame is not None:
            self._reg.accept(correction, frame, pose)
        self._last_delta = inv_pose(self._last_pose) @ pose
        self._last_dt_s = (t_ref - self._last_ns) * 1e-9 if self._last_ns is not None else 0.0
        self._last_pose = pose
        self._last_ns = t_ref
        keep_from = self._window[0].t_prev_ns if self._window else t_ref
        self._wheel = [w for w in self._wheel if w.stamp_ns > keep_from - _WHEEL_KEEP_NS]  # bounded memory
        st.degenerate += int(bool(dirs_b))
        st.used += 1
        self.stamps_ns.append(t_ref)
        self.poses.append(pose)
        return ScanResult(t_ref, pose, bool(dirs_b), failed)

    # ---- LiDAR-only: start-up window, recovery, runs without IMU ----------------------------------
    def _lidar_prior(self, t_prev: int, t_ref: int):
        """(guess, deskew knots, knot poses): gyro rotation when the IMU can give it, else the configured prior."""
        dt = (t_ref - t_prev) * 1e-9
        if self.use_imu and self.imu_mounted and self._imu and self.imu_until_ns() >= t_ref:
            v = np.zeros(3)  # world velocity of the last inter-scan motion: p_last - p_prev over its duration
            if self._last_dt_s > 0:
                v = self._last_pose[:3, :3] @ self._last_delta[:3, :3].T @ self._last_delta[:3, 3] / self._last_dt_s
            bg = np.zeros(3) if self._bias_prior[0] is None else np.asarray(self._bias_prior[0], dtype=np.float64)
            ba = np.zeros(3)
            s0 = NavState(t_prev, self._last_pose[:3, :3].copy(), self._last_pose[:3, 3].copy(), v, bg, ba)
            prop = propagate(s0, self._imu_window(t_prev), t_ref, self.ext, accel=False, planar=self.planar)
            guess = prop.poses[-1]
            if self.cfg.prior == "wheel":
                guess = self._last_pose @ self._wheel_delta(t_prev, t_ref)
            knots = (prop.stamps_ns, prop.poses) if self._deskew != "none" else (None, None)
            return guess, knots[0], knots[1], True
        cv = self._last_delta if self._last_dt_s <= 0 else _scale_delta(self._last_delta, dt / self._last_dt_s)
        prior = self.cfg.prior
        guess = self._last_pose @ (self._wheel_delta(t_prev, t_ref) if prior == "wheel" else
                                   np.eye(4) if prior == "none" else cv)
        if self._deskew == "none":
            return guess, None, None, False
        knots, rel = constant_velocity_knots(inv_pose(self._last_pose) @ guess, t_prev, t_ref)
        return guess, knots, self._last_pose[None] @ rel, False

    def _lidar_step(self, cloud: PointCloud, t_prev: int, t_ref: int, retry: bool = False,
                    window: bool = True) -> ScanResult | None:
        """Register one scan LiDAR-only. ``retry``: a scan the IMU prediction could not explain; return None
        (and change nothing) if it fails here too, since then the scan is bad, not the IMU state. ``window``:
        the scan may start the IMU state."""
        st = self.stats
        tick = time.perf_counter()
        guess, knots, knot_poses, gyro_primed = self._lidar_prior(t_prev, t_ref)
        st.times_s["propagate"] += time.perf_counter() - tick
        points = self._prepare(cloud, knots, knot_poses, t_ref)
        if points is None:
            return None
        tick = time.perf_counter()
        frame, source = self._reg.downsample(points)
        measured = self._reg.register(source, guess, adaptive=True, gate_m=_GYRO_PRIOR_GATE_M if gyro_primed else None)
        st.times_s["register"] += time.perf_counter() - tick
        if self.planar:
            measured = project_to_se2(measured)
        failed = not self._reg.empty and (not np.isfinite(measured).all()
                                          or np.allclose(measured, guess, rtol=0.0, atol=1e-12)
                                          or (gyro_primed and _jump(measured, guess, _GYRO_PRIOR_JUMP_M, _GYRO_PRIOR_JUMP_RAD)))
        if failed and retry:
            return None
        dirs_b = self._degeneracy(points, guess[:3, :3])
        pose = guess if failed else _lean_on_prior(measured, guess, dirs_b)
        if self.planar:
            pose = project_to_se2(pose)
        st.lidar_only_scans += 1
        if failed:
            st.registration_failures += 1
            self._count_lost(t_ref)
        else:
            self._lost = 0
        result = self._finish(t_ref, pose, None if failed else frame,
                              None if failed else inv_pose(guess) @ measured, dirs_b, failed)
        if self.use_imu and self.imu_mounted and self._imu and not failed and window:
            if self._first_f_base is None:
                imu = ImuBatch.concat(self._imu)
                ba = np.zeros(3) if self._bias_prior[1] is None else np.asarray(self._bias_prior[1], dtype=np.float64)
                self._first_f_base = self.ext.R_base_imu @ (imu.accel_mps2.mean(axis=0) - ba)
            self._window.append(_WindowScan(t_prev, t_ref, pose, self._wheel_speed(t_ref), cloud, len(self.poses) - 1))
            self._try_bootstrap()
        return result

    def _count_lost(self, t_ref: int) -> None:
        """One more scan in a row that no registration could place; too many end the run."""
        self._lost += 1
        if self._lost >= self.cfg.max_lost_scans:
            raise Diverged(f"lost track at scan {self.stats.scans} (stamp {t_ref * 1e-9:.3f} s): no registration, "
                           f"IMU-primed or LiDAR-only, could place {self._lost} scans in a row")

    def _wheel_speed(self, t_ns: int) -> float:
        twist = mean_twist(self._wheel, t_ns - 60_000_000, t_ns + 60_000_000) if self.cfg.use_wheel else None
        return np.nan if twist is None else twist[0]

    def _try_bootstrap(self) -> None:
        """Align the LiDAR-only window with the IMU, then replay its scans IMU-primed on a fresh map."""
        win = self._window
        stamps = np.array([w.stamp_ns for w in win], dtype=np.int64)
        if len(stamps) < 3 or (stamps[-1] - stamps[0]) * 1e-9 < self.cfg.init_window_s:
            return
        imu = ImuBatch.concat(self._imu)
        if len(imu) == 0 or imu.stamps_ns[0] > stamps[0] or imu.stamps_ns[-1] < stamps[-1]:
            self._window = win[1:]  # the IMU does not cover the window yet: slide it
            return
        poses = np.stack([w.pose for w in win])
        wheel = np.array([w.wheel_mps for w in win])
        if np.all(np.nan_to_num(wheel) == 0.0) and np.linalg.norm(poses[-1, :3, 3] - poses[0, :3, 3]) > _MOVING_M:
            wheel = np.full(len(win), np.nan)  # wheels that read exactly zero while the LiDAR moves are no wheels
        bg, ba = self._bias_prior
        ba = np.zeros(3) if ba is None else np.asarray(ba, dtype=np.float64)
        boot = align(stamps, poses, imu, self.ext, gravity_mps2=self.cfg.gravity_mps2, accel_bias=ba, gyro_bias=bg,
                     g_world=self._g_world, wheel_speeds=wheel if np.isfinite(wheel).any() else None,
                     planar=self.planar)
        if self.start is None:
            self.start = boot
        else:
            self._event("recovered", f"IMU state started again: {boot.reason}")
        self._g_world = boot.g_world
        still = boot.static
        n = boot.g_world / np.linalg.norm(boot.g_world)
        if still:  # the IMU means pin gravity and gyro bias; velocity is zero
            P = np.diag([1e-4, 1e-4, 1e-2] + [1e-6] * 3 + [1e-4] * 3 + [1e-6] * 3 + [1e-2] * 3 + [0.0] * 3)
            tilt_mps2 = 0.01
        else:  # the alignment leaves a degree or two of tilt and some velocity to the filter
            P = np.diag([1e-4, 1e-4, 1e-4] + [1e-4] * 3 + [0.04] * 3 + [2.5e-5] * 3 + [1e-2] * 3 + [0.0] * 3)
            tilt_mps2 = 0.4
        if self.planar:
            tilt_mps2 = 0.0
        P[15:18, 15:18] = tilt_mps2**2 * (np.eye(3) - np.outer(n, n)) + 1e-8 * np.eye(3)
        first = win[0]
        # the state at the first scan's start (gyro rotation, constant velocity back over one sweep), so the
        # replay de-skews that scan too
        sweep = propagate(NavState(first.t_prev_ns, np.eye(3), np.zeros(3), np.zeros(3), boot.gyro_bias, ba),
                          imu, first.stamp_ns, self.ext, accel=False)
        R0 = first.pose[:3, :3] @ sweep.state.R.T
        p0 = first.pose[:3, 3] - boot.v_start * (first.stamp_ns - first.t_prev_ns) * 1e-9
        self.state = NavState(first.t_prev_ns, R0, p0, boot.v_start.copy(), boot.gyro_bias.copy(), ba.copy(), P,
                              boot.g_world.copy())
        self._window = []
        # replay the window IMU-primed on a fresh map
        st = self.stats
        used, degenerate = st.used, st.degenerate
        del self.stamps_ns[first.out_index:], self.poses[first.out_index:]
        self._reg, self._dirs_b = None, []
        self._last_pose, self._last_ns, self._last_delta, self._last_dt_s = self.state.pose(), None, np.eye(4), 0.0
        for w in win:
            t_prev = w.t_prev_ns if self._last_ns is None else self._last_ns
            if self.imu_mode:
                self._imu_step(w.cloud, t_prev, w.stamp_ns)
            else:  # the replay lost the track again: the rest is the next window
                self._lidar_step(w.cloud, t_prev, w.stamp_ns)
        # the replayed scans were counted once already; they are IMU-primed now unless the replay lost the track
        st.used, st.degenerate = used, degenerate
        st.lidar_only_scans -= len(win)

    # ---- IMU-primed -----------------------------------------------------------------------------
    def _imu_step(self, cloud: PointCloud, t_prev: int, t_ref: int) -> ScanResult | None:
        cfg, st = self.cfg, self.stats
        tick = time.perf_counter()
        imu = self._imu_window(t_prev)
        prop = propagate(self.state, imu, t_ref, self.ext,
                         noise=cfg.fusion.imu if cfg.fusion.method == "ekf" else None, planar=self.planar)
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
        points = self._prepare(cloud, knots, knot_poses, t_ref)
        if points is None:
            self.state = saved  # the scan is skipped: keep the state where the last used scan left it
            return None
        tick = time.perf_counter()
        guess = self._guess(t_prev, t_ref)
        frame, source = self._reg.downsample(points)
        measured = self._reg.register(source, guess)
        st.times_s["register"] += time.perf_counter() - tick
        dirs_b = self._degeneracy(points, self.state.R)
        if self.planar:
            measured = project_to_se2(measured)
        failed = self._registration_failed(measured, guess)
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
                self._track_clock(t_ref, measured)
        st.times_s["fuse"] += time.perf_counter() - tick
        self._lost = 0
        result = self._finish(t_ref, pose, frame, inv_pose(guess) @ measured, dirs_b, False)
        if reason is not None:
            st.recoveries += 1
            self._event("recovery", reason + ": back to LiDAR-only scans")
            self._lose_imu_state()
        return result

    def _doubted_scan(self, cloud: PointCloud, t_prev: int, t_ref: int, measured: np.ndarray, guess: np.ndarray,
                      frame: np.ndarray, dirs_b: list, reason: str | None) -> ScanResult:
        """A scan whose registration the IMU state cannot explain: its pose comes from LiDAR-only registration
        (gated around the gyro and the last poses, not around the doubted prediction); the state follows that
        pose and keeps its velocity, biases and gravity. Several such scans in a row drop the state."""
        kept, g_world, doubt = self.state, self._g_world, self._doubt
        self._lose_imu_state()
        res = self._lidar_step(cloud, t_prev, t_ref, retry=True, window=False)
        self.state, self._g_world, self._doubt = kept, g_world, doubt
        if res is None:  # LiDAR-only failed: the prediction-gated registration is all there is
            pose = _lean_on_prior(measured, guess, dirs_b)
            res = self._finish(t_ref, pose, frame, None, dirs_b, False)
        self.state.R, self.state.p = res.pose[:3, :3].copy(), res.pose[:3, 3].copy()
        if reason is not None:
            self.stats.recoveries += 1
            self._event("recovery", reason + ": back to LiDAR-only scans")
            self._lose_imu_state()
        return res

    def _track_clock(self, t_ref: int, measured: np.ndarray) -> None:
        if self.clock is None or self.clock.done:
            return
        self.clock.add_pose(t_ref, measured @ self.ext.T_base_lidar)
        delta = self.clock.propose(self.state.bg, self.stats.scans)
        if delta:
            self._shift_imu(delta)

    def _implausible(self, measured: np.ndarray, dirs_b: list) -> str | None:
        """A pose innovation far outside its covariance for several scans in a row (EKF only)."""
        fc = self.cfg.fusion
        if fc.method != "ekf":
            return None
        dirs_w = [self.state.R @ d for d in dirs_b]
        nis = pose_innovation_nis(self.state, measured, fc.rotation_sigma_rad,
                                  position_noise(fc.position_sigma_m, dirs_w, fc.degenerate_sigma_m))
        self._doubt = self._doubt + 1 if nis > _NIS_LIMIT else 0
        if self._doubt >= _NIS_SCANS:
            return f"prediction and registration disagreed for {self._doubt} scans (NIS {nis:.0f})"
        return None

    def _state_implausible(self) -> str | None:
        s = self.state
        speed = float(np.linalg.norm(s.v))
        if not (np.isfinite(s.v).all() and np.isfinite(s.bg).all() and np.isfinite(s.ba).all()):
            return "the IMU state became non-finite"
        if speed > self.cfg.max_speed_mps:
            return f"speed {speed:.1f} m/s beyond max_speed_mps"
        if np.linalg.norm(s.bg) > _MAX_BIAS_GYRO_RADPS or np.linalg.norm(s.ba) > _MAX_BIAS_ACCEL_MPS2:
            return f"IMU biases implausible (gyro {np.linalg.norm(s.bg):.2f} rad/s, accel {np.linalg.norm(s.ba):.2f} m/s^2)"
        return None

    def _registration_failed(self, measured: np.ndarray, guess: np.ndarray) -> bool:
        """Non-finite, untouched (no correspondence at all), or implausibly far from the IMU prediction."""
        if not np.isfinite(measured).all():
            return True
        if self._reg.empty:
            return False
        if np.allclose(measured, guess, rtol=0.0, atol=1e-12):  # ICP returns the guess itself when nothing matched
            return True
        return _jump(measured, guess, _MAX_JUMP_M, _MAX_JUMP_RAD)

    def _guess(self, t_prev: int, t_ref: int) -> np.ndarray:
        prior = self.cfg.prior
        if prior == "imu":
            return self.state.pose()
        if prior == "constant-velocity":
            return self._last_pose @ self._last_delta
        if prior == "wheel":
            return self._last_pose @ self._wheel_delta(t_prev, t_ref)
        return self._last_pose.copy()

    def _wheel_delta(self, t0: int, t1: int) -> np.ndarray:
        """Planar motion integrated from wheel speed and yaw rate over [t0, t1] (lecture's kinematics)."""
        twist = mean_twist(self._wheel, t0 - 100_000_000, t1)
        if twist is None:
            return self._last_delta
        return planar_delta(twist[0], twist[1], (t1 - t0) * 1e-9)

    def _wheel_update(self, t0: int, t1: int) -> None:
        """Wheel speed over the scan (forward, no side slip) corrects the predicted velocity."""
        if not self.cfg.use_wheel or not self._wheel:
            return
        twist = mean_twist(self._wheel, t0, t1 + 20_000_000)
        if twist is None:
            return
        if twist == (0.0, 0.0) and np.linalg.norm(self.state.v) > _MOVING_MPS:
            self.stats.wheel_zero_skipped += 1  # an all-zero twist while moving: a pose source, not wheels
            return
        v_body = np.array([twist[0], 0.0, 0.0])
        fc = self.cfg.fusion
        if fc.method == "ekf":
            s = fc.wheel_speed_sigma_mps
            ekf_body_velocity_update(self.state, v_body, np.array([s, 2 * s, 2 * s]))
        else:
            complementary_velocity_update(self.state, v_body, fc.wheel_beta)
        self.stats.wheel_updates += 1

    def _correct(self, measured: np.ndarray, dirs_b: list[np.ndarray], dt_s: float) -> np.ndarray:
        fc = self.cfg.fusion
        dirs_w = [self.state.R @ d for d in dirs_b]
        if fc.method == "ekf":
            cov = position_noise(fc.position_sigma_m, dirs_w, fc.degenerate_sigma_m)
            ekf_pose_update(self.state, measured, fc.rotation_sigma_rad, cov)
        else:
            complementary_update(self.state, measured, fc.alpha, dt_s, self.ext.R_base_imu, dirs_w)
        if self.planar:
            flatten_planar(self.state)
        return self.state.pose()


@dataclass
class _WindowScan:
    """A scan registered LiDAR-only while the IMU state is (re)started, kept to be replayed IMU-primed."""

    t_prev_ns: int
    stamp_ns: int
    pose: np.ndarray
    wheel_mps: float
    cloud: PointCloud
    out_index: int


def _jump(measured: np.ndarray, guess: np.ndarray, max_m: float, max_rad: float) -> bool:
    """The registration moved further than ``max_m`` or turned more than ``max_rad`` from its guess."""
    jump = inv_pose(guess) @ measured
    angle = np.arccos(np.clip((np.trace(jump[:3, :3]) - 1.0) / 2.0, -1.0, 1.0))
    return bool(np.linalg.norm(jump[:3, 3]) > max_m or angle > max_rad)


def _lean_on_prior(measured: np.ndarray, guess: np.ndarray, dirs_b: list[np.ndarray]) -> np.ndarray:
    """The measured pose, except along directions the scan cannot see, where the prior is kept."""
    pose = measured.copy()
    if dirs_b:
        R = guess[:3, :3]
        dp = measured[:3, 3] - guess[:3, 3]
        for d in dirs_b:
            dw = R @ d
            dp = dp - dw * (dw @ dp)
        pose[:3, 3] = guess[:3, 3] + dp
    return pose


def _scale_delta(delta: np.ndarray, factor: float) -> np.ndarray:
    """The relative motion ``delta`` stretched to ``factor`` of its duration (constant velocity)."""
    if abs(factor - 1.0) < 1e-9:
        return delta
    out = np.eye(4)
    out[:3, :3] = so3_exp(so3_log(delta[:3, :3]) * factor)
    out[:3, 3] = delta[:3, 3] * factor
    return out


__all__ = ["Diverged", "LioOdometry", "ScanResult", "OdomStats"]
