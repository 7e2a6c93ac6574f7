"""IMU-primed scan matching: the lecture's LIO pipeline on kiss-icp's registration and voxel map.

Per scan with an IMU state: propagate it to the scan's reference instant (its end by default), de-skew every point
with the propagated pose at its own stamp, register the de-skewed scan to the local map starting from the IMU
prediction, check the geometry for degenerate directions, then correct the state (EKF or complementary filter) so
the corrected velocity and biases prime the next scan (``imu_step``).

The IMU state is never assumed: the first scans are registered LiDAR-only (``lidar_step``: gyro rotation, constant-
velocity translation) until ``init_window_s`` of poses can be aligned with the IMU (``startup``). The same happens
after a lost track (``recovery``, ``guards``). LiDAR and IMU gaps are in ``gaps`` and ``bridge``. The internal
world frame is the first scan's base frame; ``output_alignment`` levels it by the gravity found.
"""

from __future__ import annotations

import numpy as np

from ...config.odom import OdomConfig
from ...geometry import gravity_aligned_rotation
from ...model.calibration import Extrinsics
from ...model.records import ImuBatch, OdometryRecord, PointCloud
from ...model.trajectory import Rows
from ..imu import NavState, gravity_vector
from .bootstrap import Bootstrap
from .bridge import bridge
from .clock_offset import ClockOffsetTracker
from .gaps import bridge_refused
from .imu_step import imu_step
from .lidar_step import lidar_step
from .startup import replay, specific_force_levels, try_start
from .state import OdomState, OdomStats, ScanResult, Settings


class LioOdometry:
    """Feed IMU batches, wheel records and scans (in time order); get one pose per scan."""

    def __init__(self, cfg: OdomConfig, T_base_lidar: np.ndarray, *, use_imu: bool, planar: bool,
                 gyro_bias: np.ndarray | None = None, accel_bias: np.ndarray | None = None,
                 gyro_only: bool = False, scan_sink=None) -> None:
        """``gyro_only``: every scan is registered LiDAR-only, primed and de-skewed by the gyro's rotation (once
        the IMU is mounted) but never fused with an IMU state: the poses are the registration's own.
        ``scan_sink(stamp_ns, points or None)``: see ``OdomState.scan_sink``."""
        settings = Settings(cfg, use_imu, planar, gyro_only, (gyro_bias, accel_bias),
                            imu_prior=use_imu and cfg.prior == "imu", deskew=cfg.resolved_deskew())
        self.run = OdomState(settings, Extrinsics(np.eye(4), T_base_lidar))
        self.run.nav.g_world = gravity_vector(cfg.gravity_mps2) if planar else None
        self.run.scan_sink = scan_sink

    # ---- inputs -------------------------------------------------------------------------------
    def set_imu_extrinsic(self, T_base_imu: np.ndarray) -> None:
        o = self.run
        o.ext = Extrinsics(np.asarray(T_base_imu, dtype=np.float64), o.ext.T_base_lidar)
        o.imu_mounted = True
        if o.cfg.estimate_time_offset and not o.settings.planar:
            o.clock = ClockOffsetTracker()

    def add_imu(self, batch: ImuBatch) -> None:
        o = self.run
        batch = o.imu.add(batch)
        if o.clock is not None:
            o.clock.add_imu(batch.stamps_ns, batch.gyro_radps)

    def add_wheel(self, rec: OdometryRecord) -> None:
        self.run.wheel.append(rec)

    def close_clock(self) -> None:
        """The clock tracker's closing estimate, once every scan is done (see ``ClockOffsetTracker.close``)."""
        o = self.run
        if o.clock is not None and o.nav.state is not None:
            o.clock.close(o.nav.state.bg, o.stats.scans)

    # ---- one scan -----------------------------------------------------------------------------
    def process(self, cloud: PointCloud) -> ScanResult | None:
        o = self.run
        cfg, st, track = o.cfg, o.stats, o.track
        st.scans += 1
        if len(cloud.points) < cfg.registration.min_points:
            st.skipped_few_points += 1
            return None
        t_ref = cloud.end_ns if cfg.scan_reference == "end" else cloud.start_ns
        if track.last_ns is not None and t_ref <= track.last_ns:
            st.skipped_out_of_order += 1  # a scan ending before the previous one cannot be placed
            return None
        t_prev = cloud.start_ns if track.last_ns is None else track.last_ns
        if (t_ref - t_prev) * 1e-9 > cfg.max_gap_s:  # bridged by the IMU state if it can, else restart
            st.time_gaps += 1
            refused = bridge_refused(o.nav.state is not None, o.imu_window, t_prev, t_ref, cfg.max_bridge_s)
            if refused is None:
                return bridge(o, cloud, t_prev, t_ref)
            o.event("time gap", f"{(t_ref - t_prev) * 1e-9:.3g} s without a scan ({refused}): restarted from "
                                "the LiDAR")
            o.lose_imu_state()
            track.last_delta = np.eye(4)
            t_prev = cloud.start_ns
        return self._step(cloud, t_prev, t_ref)

    def _step(self, cloud: PointCloud, t_prev: int, t_ref: int) -> ScanResult | None:
        """IMU-primed with an IMU state, else LiDAR-only; a LiDAR-only scan that joins the start-up window may start
        the IMU state, whose window is then replayed through this step."""
        o = self.run
        if o.nav.state is not None:
            return imu_step(o, cloud, t_prev, t_ref)
        o.startup.due = False
        result = lidar_step(o, cloud, t_prev, t_ref)
        if o.startup.due:
            o.startup.due = False
            window = try_start(o)
            if window is not None:
                replay(o, window, self._step)
        return result

    # ---- outputs ------------------------------------------------------------------------------
    @property
    def poses(self) -> Rows:
        """T_world_base per used scan (internal world frame)."""
        return self.run.track.poses

    @property
    def stamps_ns(self) -> Rows:
        return self.run.track.stamps_ns

    @property
    def predicted_ns(self) -> set[int]:
        """Stamps of scans whose pose is their IMU prediction, not a registered one."""
        return self.run.track.predicted_ns

    @property
    def settled(self) -> int:
        """How many leading poses can no longer change: all but the start-up window's, which are replaced
        when the IMU state starts from them."""
        scans = self.run.startup.held or self.run.startup.scans  # held scans are replayed with the window
        return scans[0].out_index if scans else len(self.poses)

    @property
    def stats(self) -> OdomStats:
        return self.run.stats

    @property
    def events(self) -> list[dict]:
        """Recoveries, gaps, restarts and clock shifts: kind, scan, time, reason."""
        return self.run.events

    @property
    def state(self) -> NavState | None:
        return self.run.nav.state

    @property
    def imu_mode(self) -> bool:
        return self.run.nav.state is not None

    @property
    def start(self) -> Bootstrap | None:
        """How the IMU state first started (None: never)."""
        return self.run.startup.bootstrap

    @property
    def ext(self) -> Extrinsics:
        return self.run.ext

    @property
    def imu_mounted(self) -> bool:
        """T_base_imu is known (set when the first IMU message names its frame)."""
        return self.run.imu_mounted

    @property
    def clock(self) -> ClockOffsetTracker | None:
        return self.run.clock

    @property
    def imu_shift_ns(self) -> int:
        """What the online clock tracker has added to the IMU stamps so far (beyond the calibration's offset)."""
        return self.run.imu.shift_ns

    @property
    def voxel_size_m(self) -> float | None:
        """The map's voxel size, once the first scan has set it."""
        return self.run.reg.voxel_size_m if self.run.reg is not None else None

    def imu_until_ns(self) -> int | None:
        return self.run.imu.until_ns()

    def output_alignment(self) -> np.ndarray:
        """T_out_world: levels the internal world frame (the first scan's base) by the gravity found."""
        T = np.eye(4)
        source = self.level_source()
        if source == "gravity":  # gravity as the last healthy IMU state (or the start-up) had it
            T[:3, :3] = gravity_aligned_rotation(-self.run.nav.g_world)
        elif source == "specific force":  # never aligned, but standing still
            T[:3, :3] = gravity_aligned_rotation(self.run.startup.first_f_base)
        return T

    def level_source(self) -> str:
        """What ``output_alignment`` levels by: "gravity" (the IMU state's), "specific force" (never aligned,
        standing still), "none" (never aligned while moving, or no IMU: the first scan's base frame as it is)."""
        if self.run.nav.g_world is not None:
            return "gravity"
        if self.run.startup.first_f_base is not None and specific_force_levels(self.run):
            return "specific force"
        return "none"
