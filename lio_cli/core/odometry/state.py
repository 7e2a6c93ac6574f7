"""The odometry loop's state, as explicit objects: the track, the IMU buffer, the IMU state, the start-up window,
gaps, guards, the degeneracy schedule; and what a step returns (``ScanResult``) or raises (``Diverged``)."""

from __future__ import annotations

from array import array
from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np

from ...config.odom import OdomConfig
from ...errors import ProcessingError
from ...geometry import inv_pose
from ...model.calibration import Extrinsics
from ...model.records import ImuBatch, OdometryRecord, PointCloud
from ...model.trajectory import Rows
from ..imu import NavState
from .bootstrap import Bootstrap
from .clock_offset import ClockOffsetTracker
from .registration import ScanRegistration
from .tuning import MIN_VELOCITY_DT_S


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
    capped_icp_scans: int = 0  # IMU-primed scans registered with steady_ or slow_iterations
    predicted_scans: int = 0  # slowly turning scans whose pose is the IMU prediction, unregistered (slow_register_every)
    doubted_scans: int = 0  # IMU-primed scans whose registration the IMU state could not explain: placed LiDAR-only
    recoveries: int = 0
    time_gaps: int = 0
    # CPU seconds of the process per stage (all threads: kiss-icp's too), so that a loaded machine does not inflate them
    times_s: dict[str, float] = field(default_factory=lambda: {"propagate": 0.0, "deskew": 0.0, "register": 0.0,
                                                               "degeneracy": 0.0, "fuse": 0.0})
    register_s: array = field(default_factory=lambda: array("d"))  # each registration's CPU time (8 bytes a scan)

    def counts(self) -> dict[str, int]:
        """Every counter (not the times), for metrics."""
        counts = {k: v for k, v in vars(self).items() if k not in ("scans", "times_s", "register_s")}
        return {"total": self.scans, **counts}

    def registered(self, seconds: float) -> None:
        """Count one registration's time (the register stage of one scan, a retry being another)."""
        self.times_s["register"] += seconds
        self.register_s.append(seconds)

    def register_ms(self) -> dict[str, float | None]:
        """Median and 90th percentile of the registrations' times, in ms (None before any)."""
        if not self.register_s:
            return {"register_median": None, "register_p90": None}
        ms = np.frombuffer(self.register_s, dtype=np.float64) * 1000.0
        return {"register_median": round(float(np.median(ms)), 3), "register_p90": round(float(np.percentile(ms, 90)), 3)}


@dataclass(frozen=True)
class Settings:
    """What a run fixes at its start."""

    cfg: OdomConfig
    use_imu: bool
    planar: bool
    gyro_only: bool  # every scan LiDAR-only (gyro-primed), never fused with an IMU state
    bias_prior: tuple  # (gyro bias, accel bias) from a calibration file, each or None
    imu_prior: bool  # scans are primed by the IMU state
    deskew: str  # the resolved de-skew: "imu", "constant-velocity" or "none"

    @property
    def imu_noise(self):
        """The IMU noise propagation carries (the EKF's), or None (the complementary filter keeps no covariance)."""
        return self.cfg.fusion.imu if self.cfg.fusion.method == "ekf" else None


@dataclass
class Track:
    """The trajectory so far (internal world frame) and its last motion; the start-up window's LiDAR-only poses
    are replaced once the IMU state starts."""

    stamps_ns: Rows = field(default_factory=lambda: Rows((), np.int64))  # (8 bytes a scan, not a Python int)
    poses: Rows = field(default_factory=lambda: Rows((4, 4)))  # (128 bytes a scan, not an array object)
    last_pose: np.ndarray = field(default_factory=lambda: np.eye(4))
    last_delta: np.ndarray = field(default_factory=lambda: np.eye(4))  # T_last-before_last, over last_dt_s
    last_ns: int | None = None
    last_dt_s: float = 0.0
    predicted_ns: set[int] = field(default_factory=set)  # scans whose pose is their IMU prediction, unregistered
    predicted_run: int = 0  # such scans since the last registered one

    def append(self, t_ref: int, pose: np.ndarray) -> None:
        """Add a scan's pose and update the last motion."""
        delta = inv_pose(self.last_pose) @ pose
        dt_s = (t_ref - self.last_ns) * 1e-9 if self.last_ns is not None else 0.0
        if 0.0 < dt_s < MIN_VELOCITY_DT_S:
            # too close to give a velocity: the interval is extended back over the previous one (if any)
            delta, dt_s = (self.last_delta @ delta, dt_s + self.last_dt_s) if self.last_dt_s > 0.0 else (np.eye(4), 0.0)
        self.last_delta, self.last_dt_s = delta, dt_s
        self.last_pose = pose
        self.last_ns = t_ref
        self.stamps_ns.append(t_ref)
        self.poses.append(pose)

    def restart_at(self, index: int, pose: np.ndarray) -> None:
        """Drop the poses from ``index`` on and start the motion again from ``pose``."""
        del self.stamps_ns[index:], self.poses[index:]
        self.last_pose, self.last_ns, self.last_delta, self.last_dt_s = pose, None, np.eye(4), 0.0


@dataclass
class ImuBuffer:
    """IMU batches not yet consumed, on the LiDAR's clock (shifted by what the clock tracker found)."""

    batches: list[ImuBatch] = field(default_factory=list)
    shift_ns: int = 0  # correction added to IMU stamps so far

    def add(self, batch: ImuBatch) -> ImuBatch:
        """Buffer ``batch`` on the LiDAR's clock; return it as buffered."""
        if self.shift_ns:
            batch = batch.shifted(self.shift_ns)
        self.batches.append(batch)
        return batch

    def shift(self, delta_ns: int) -> None:
        """Move every sample, buffered and to come, by ``delta_ns``."""
        self.shift_ns += delta_ns
        self.batches = [b.shifted(delta_ns) for b in self.batches]

    def until_ns(self) -> int | None:
        return int(self.batches[-1].stamps_ns[-1]) if self.batches else None

    def window(self, t0_ns: int, hold_ns: int | None = None) -> ImuBatch:
        """Samples from just before ``t0_ns`` (or ``hold_ns``, if earlier) on; older ones are dropped."""
        if hold_ns is not None:
            t0_ns = min(t0_ns, hold_ns)
        imu = ImuBatch.concat(self.batches)
        if len(imu):
            keep = max(0, int(np.searchsorted(imu.stamps_ns, t0_ns)) - 2)
            imu = ImuBatch(imu.frame_id, imu.stamps_ns[keep:], imu.gyro_radps[keep:], imu.accel_mps2[keep:])
        self.batches = [imu] if len(imu) else []
        return imu


@dataclass
class Nav:
    """The IMU state (None: LiDAR-only scans) and gravity as the last healthy state (or the start-up) had it."""

    state: NavState | None = None
    g_world: np.ndarray | None = None


@dataclass
class WindowScan:
    """A scan registered LiDAR-only while the IMU state is (re)started, kept to be replayed IMU-primed."""

    t_prev_ns: int
    stamp_ns: int
    pose: np.ndarray
    wheel_mps: float
    cloud: PointCloud
    out_index: int


@dataclass
class StartUp:
    """The LiDAR-only scans that will start the IMU state, and the first start's result."""

    scans: list[WindowScan] = field(default_factory=list)
    held: list[WindowScan] = field(default_factory=list)  # slid out of a first window the IMU could not explain
    due: bool = False  # a scan joined the window: try to start
    first_f_base: np.ndarray | None = None  # mean specific force (base axes) around the first scan
    bootstrap: Bootstrap | None = None  # how the IMU state first started

    @property
    def hold_ns(self) -> int | None:
        """The window's first scan start: IMU samples from there on are kept until it is aligned."""
        first = self.held or self.scans
        return first[0].t_prev_ns if first else None


@dataclass
class Health:
    """Counters of the guards."""

    doubt: int = 0  # IMU-mode scans in a row whose innovation was implausible
    lost: int = 0  # scans in a row that no registration could place
    map_restarts: int = 0


@dataclass
class GapState:
    imu_gap_from: tuple | None = None  # (pose, stamp, event) before an IMU gap the scans are in
    blind_tree: tuple | None = None  # (map, its scans, its k-d tree) for scans over an IMU gap


@dataclass
class DegeneracySchedule:
    """When the scene's geometry is analysed again, and what the last analysis found."""

    dirs_b: list[np.ndarray] = field(default_factory=list)  # degenerate directions of the last analysed scan
    due: tuple[int, int] = (0, -1)  # (no analysis before this many scans are used, the scan analysed last)
    clear_scene: bool = False  # the last analysis found the scene far from degenerate

    def reset(self) -> None:
        """A new scene (a new map): analysed at once."""
        self.due = (0, -1)


@dataclass
class OdomState:
    """Everything the steps read and change, as the objects above."""

    settings: Settings
    ext: Extrinsics
    stats: OdomStats = field(default_factory=OdomStats)
    events: list[dict] = field(default_factory=list)  # recoveries and time gaps: scan, time, reason
    track: Track = field(default_factory=Track)
    imu: ImuBuffer = field(default_factory=ImuBuffer)
    wheel: list[OdometryRecord] = field(default_factory=list)
    nav: Nav = field(default_factory=Nav)
    startup: StartUp = field(default_factory=StartUp)
    health: Health = field(default_factory=Health)
    gaps: GapState = field(default_factory=GapState)
    degeneracy: DegeneracySchedule = field(default_factory=DegeneracySchedule)
    reg: ScanRegistration | None = None  # the local map, once the first scan set its voxel size
    clock: ClockOffsetTracker | None = None  # online IMU-LiDAR time offset (once the IMU is mounted)
    imu_mounted: bool = False  # T_base_imu is known
    # told each placed scan's de-skewed points in range (base frame at its stamp), or None when the scan stays out of
    # the map; a replayed scan is told again
    scan_sink: Callable[[int, np.ndarray | None], None] | None = None

    @property
    def cfg(self) -> OdomConfig:
        return self.settings.cfg

    def imu_window(self, t0_ns: int) -> ImuBatch:
        """IMU samples from just before ``t0_ns`` on (the start-up window's kept until it is aligned)."""
        return self.imu.window(t0_ns, self.startup.hold_ns)

    def imu_ready(self) -> bool:
        """The IMU can prime a scan: wanted, mounted, and some samples buffered."""
        return self.settings.use_imu and self.imu_mounted and bool(self.imu.batches)

    def event(self, kind: str, reason: str) -> dict:
        """Record an event (and return it: a gap's reason is completed as its scans come)."""
        event = {"kind": kind, "scan": self.stats.scans, "after_stamp_ns": self.track.last_ns, "reason": reason}
        self.events.append(event)
        return event

    def lose_imu_state(self, keep_clock: bool = False) -> None:
        """Drop the IMU state (LiDAR-only scans follow); ``keep_clock``: the clock estimate keeps its window (a
        doubted scan, whose state comes back)."""
        self.nav.state = None  # gravity survives in nav.g_world
        if self.clock is not None and not keep_clock:
            self.clock.reset()
        self.startup.scans, self.startup.held = [], []
        self.health.doubt = 0
        self.gaps.imu_gap_from = None  # a restart ends any IMU gap the scans were in
