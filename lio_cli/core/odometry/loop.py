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

``LioOdometry`` is assembled from mixins: the IMU-primed step and what every step shares (de-skew, degeneracy,
the pose's bookkeeping) in ``odometry_scan``, the LiDAR-only step in ``odometry_lidar``, the state updates and
guards in ``odometry_updates``, the start and restart of the IMU state in ``odometry_restart``, LiDAR gaps
bridged by the IMU state and scans over IMU gaps in ``odometry_gaps``.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from ...config.odom import OdomConfig
from ...geometry import gravity_aligned_rotation
from ...model.calibration import Extrinsics
from ...model.records import ImuBatch, OdometryRecord, PointCloud
from .bootstrap import Bootstrap
from .clock_offset import ClockOffsetTracker
from ..imu import NavState, gravity_vector
from .gaps import Gaps
from .lidar_step import Diverged, LidarSteps, ScanResult
from .restart import Restart, WindowScan
from .imu_step import ScanSteps
from .updates import StateUpdates
from .registration import ScanRegistration

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
    doubted_scans: int = 0  # IMU-primed scans whose registration the IMU state could not explain: placed LiDAR-only
    recoveries: int = 0
    time_gaps: int = 0
    times_s: dict[str, float] = field(default_factory=lambda: {"propagate": 0.0, "deskew": 0.0, "register": 0.0,
                                                               "degeneracy": 0.0, "fuse": 0.0})

    def counts(self) -> dict[str, int]:
        """Every counter (not the times), for metrics."""
        counts = {k: v for k, v in vars(self).items() if k not in ("scans", "times_s")}
        return {"total": self.scans, **counts}

class LioOdometry(ScanSteps, StateUpdates, Restart, LidarSteps, Gaps):
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
        self._clear_scene = False  # the last degeneracy analysis found the scene far from degenerate
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
            batch = batch.shifted(self._shift_ns)
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
        self._imu = [b.shifted(delta_ns) for b in self._imu]
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

    def _lose_imu_state(self, keep_clock: bool = False) -> None:
        """Drop the IMU state (LiDAR-only scans follow); ``keep_clock``: the clock estimate keeps its window (a
        doubted scan, whose state comes back)."""
        self.state = None  # gravity survives in _g_world, as the last healthy state had it
        if self.clock is not None and not keep_clock:
            self.clock.reset()
        self._window = []
        self._doubt = 0
        self._imu_gap_from = None  # a restart ends any IMU gap the scans were in


__all__ = ["Diverged", "LioOdometry", "ScanResult", "OdomStats"]
