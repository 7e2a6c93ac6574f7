"""What ``lio calibrate`` reads from a log: the raw IMU and wheel arrays, and the LiDAR's trajectory from the
odometry core run over the scans.

The trajectory is of the LiDAR itself (the odometry's base is the LiDAR: ``T_base_lidar`` = identity), in the
frame of its first scan, at each scan's end on the LiDAR clock. The first pass is LiDAR-only, so nothing in
it depends on the IMU being calibrated; a refining pass primes registration and de-skews with the gyro's
rotation through the previous estimates (``T_lidar_imu``, the clock offset, the gyro bias), which sharpens
the trajectory on fast motion, yet keeps each pose the registration's own: a pose fused with the IMU state
follows the gyro through the estimated mounting, so the estimates would come back as they went in (about a
weakly excited axis entirely). Neither uses /tf_static: the point is to find what it should say.
"""

from __future__ import annotations

from collections import deque
from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np

from ...config.calibrate import CalibrateConfig
from ...config.odom import OdomConfig
from ...core.calibration.map_refine import Sweep, thin_sweep
from ...core.odometry import Diverged, LioOdometry
from ...errors import InputError, ProcessingError
from ...io.messages.pointcloud import parse_time_convention
from ...io.logs.base import LogReader
from ...io.sensors.stream import SensorStream, read_imu as read_imu_topic
from ...model.records import ImuBatch, PointCloud

_IMU_WAIT_NS = 500_000_000  # a scan waits at most this long (log time) for IMU covering its end

Progress = Callable[[int, int | None], None]


@dataclass
class SensorArrays:
    """Raw IMU samples (IMU clock and frame) and wheel odometry (forward speed, yaw rate of the base)."""

    imu_frame: str = ""
    imu: ImuBatch | None = None
    wheel_stamps_ns: np.ndarray = field(default_factory=lambda: np.zeros(0, np.int64))
    wheel_linear_mps: np.ndarray = field(default_factory=lambda: np.zeros(0))
    wheel_angular_radps: np.ndarray = field(default_factory=lambda: np.zeros(0))
    lidar_frame: str = ""
    scans: int = 0
    last_scan_end_ns: int | None = None  # of every scan read, registered or not
    # the log's first scans as read, (start, end, points thinned): the ground seen while still (``rest``)
    first_scans: list[tuple[int, int, np.ndarray]] = field(default_factory=list)

    @property
    def has_wheels(self) -> bool:
        return len(self.wheel_stamps_ns) >= 3


class PassProgress:
    """One count over every pass of a calibration: scans processed of the scans the passes will process
    (``plan`` corrects the total once the passes' stretches are known)."""

    def __init__(self, progress: Progress | None, total: int) -> None:
        self.progress, self.total, self.done = progress, total, 0

    def plan(self, remaining: int) -> None:
        self.total = self.done + max(int(remaining), 0)

    def step(self) -> None:
        self.done += 1
        if self.progress:
            self.progress(self.done, max(self.total, self.done))


@dataclass
class LidarTrajectory:
    stamps_ns: np.ndarray  # (N,) int64, scan ends on the LiDAR clock
    T_world_lidar: np.ndarray  # (N,4,4), world = the LiDAR at the first scan
    scans_used: int
    scans_total: int
    description: str


# 2D scans (a LaserScan) register too loosely alone to time the IMU: there the refining passes fuse the IMU,
# the registration's per-scan position (m) and rotation (rad) sigmas far below odom's, first tighter
PLANAR_FUSION_SIGMAS = ((0.001, 0.0001), (0.01, 0.001))
PARTIAL_SPAN = 1 / 4  # a refining pass before the last covers this share of the scans' span (3D scans)...
PARTIAL_MIN_NS = 10_000_000_000  # ...but at least this much of it
FIRST_SPAN = 1 / 2  # the LiDAR-only pass, when refining passes follow (3D scans), registers this share...
FIRST_MIN_NS = 20_000_000_000  # ...but at least this much (all of the log when that is not less)
FIRST_SCANS_NS = 5_000_000_000  # the scans starting this soon after the first are kept (``first_scans``)...
FIRST_SCAN_POINTS = 20000  # ...thinned to at most this many points each
DEGENERACY_EVERY = 5  # scans between analyses of the geometry (odom: 2); a calibration log's scene changes slowly
WHEEL_PASS_VOXEL = 0.5  # the 2D wheel pass's map voxel, as a share of the odometry's (halves its registration jitter)


def refine_spans(passes: int, planar: bool) -> list[float]:
    """The share of the log each refining pass covers, from the start: the last pass all of it (the final
    estimates), the ones before only a part: a pass brings the clock offset a fixed share (about a fifth, through
    the de-skew) of its error closer, however long it is, so short passes converge it as well and cheaper. 2D
    scans: at most the fused passes of ``PLANAR_FUSION_SIGMAS``, each over the whole log."""
    if planar:
        return [1.0] * min(passes, len(PLANAR_FUSION_SIGMAS))
    return [1.0 if k == passes else PARTIAL_SPAN for k in range(1, passes + 1)]


def first_span_ns(passes: int, planar: bool, duration_ns: int) -> int | None:
    """How much of the log (from its first scan) the LiDAR-only pass registers; None: all of it. It only seeds
    the gyro-primed passes (the last of which registers everything and gives the final estimates), and its
    registration, unprimed through the motion, is the slowest of the passes: half a long log seeds them as well.
    2D scans, and a LiDAR-only pass that is the last, register all."""
    span = max(int(FIRST_SPAN * duration_ns), FIRST_MIN_NS)
    return None if planar or passes < 1 or span >= duration_ns else span


def pass_until(span: float, first_ns: int, last_ns: int) -> int | None:
    """Stamp where a refining pass covering ``span`` of the scans from ``first_ns`` to ``last_ns`` stops (None:
    at the end of the log)."""
    until = first_ns + max(int(span * (last_ns - first_ns)), PARTIAL_MIN_NS)
    return None if span >= 1.0 or until >= last_ns else until


def pass_config(cfg: CalibrateConfig, primed: bool, fused: tuple[float, float] | None = None) -> OdomConfig:
    """The odometry settings of a pass: LiDAR-only without de-skew, or gyro-primed (the gyro's rotation, through
    the previous estimates, primes the registration and de-skews, with constant-velocity translation), or with
    ``fused`` sigmas IMU-primed with the pose fused; no online clock tracking (the offset is what is being
    estimated) and no wheels (they are being calibrated)."""
    fusion = {"degeneracy_every": DEGENERACY_EVERY}
    if fused is not None:
        fields = {"prior": "imu", "deskew": "imu",
                  "fusion": {**fusion, "position_sigma_m": fused[0], "rotation_sigma_rad": fused[1]}}
    else:
        fields = {"prior": "constant-velocity", "deskew": "constant-velocity" if primed else "none", "fusion": fusion}
    return OdomConfig.model_validate({
        "input": cfg.input.model_dump(), **fields, "use_wheel": False, "estimate_time_offset": False,
        "scan_reference": "end", "frame": "lidar", "registration": cfg.registration.model_dump(),
    })


def wheel_pass_config(cfg: CalibrateConfig, voxel_m: float | None) -> CalibrateConfig:
    """``cfg`` for the gyro-primed pass of 2D scans the wheel scales are measured against: its map voxel
    ``WHEEL_PASS_VOXEL`` times ``voxel_m`` (the odometry's, found from the scans' ranges) unless the
    configuration gave one."""
    if cfg.registration.voxel_size_m is not None or voxel_m is None:
        return cfg
    reg = cfg.registration.model_copy(update={"voxel_size_m": WHEEL_PASS_VOXEL * voxel_m})
    return cfg.model_copy(update={"registration": reg})


class LidarPass:
    """One pass over the log's stream feeding ``LioOdometry`` (base = LiDAR); optionally gathers the IMU and
    wheel arrays on the way."""

    def __init__(self, reader: LogReader, cfg: CalibrateConfig, topics: dict[str, str | None], planar: bool,
                 counter: PassProgress | None = None) -> None:
        self.reader, self.cfg, self.topics, self.planar, self.counter = reader, cfg, topics, planar, counter
        self.pending: deque[PointCloud] = deque()
        self.mid_ns: dict[int, int] = {}  # scan end -> middle of its sweep
        self.done = 0
        self.stats: dict = {}  # the odometry's scan counts and events of the last run
        self.sweep_voxel: float | None = None  # keep each scan thinned to this share of the odometry's voxel...
        self.sweeps: dict[int, Sweep] = {}  # ...by its end stamp (the pose's stamp of a gyro-primed pass)
        self.voxel_m: float | None = None  # the odometry's map voxel

    def run(self, imu_mounting: tuple[np.ndarray, float, np.ndarray | None] | None = None,
            gather: bool = False, until_ns: int | None = None, span_ns: int | None = None,
            fused_sigmas: tuple[float, float] | None = None) -> tuple[LidarTrajectory, SensorArrays]:
        """``imu_mounting`` = (T_lidar_imu, imu_time_offset_s, gyro_bias) for a gyro-primed pass, None for LiDAR
        only; with ``fused_sigmas`` (one of ``PLANAR_FUSION_SIGMAS``) IMU-primed and fused instead. ``gather``:
        also collect the IMU and wheel arrays (of the whole log, whatever the scans registered). ``until_ns``:
        register no scan stamped after it; ``span_ns``: none ending more than this after the first scan's end."""
        cfg = self.cfg
        with_imu = imu_mounting is not None
        fused = fused_sigmas if with_imu else None
        conv = parse_time_convention(cfg.input.point_time) if cfg.input.point_time else None
        wanted = {"lidar": self.topics["lidar"]}
        if with_imu or gather:
            wanted["imu"] = self.topics.get("imu")
        if gather:
            wanted["wheel"] = self.topics.get("wheel")
        stream = SensorStream(self.reader, wanted, convention=conv, strict=False)
        ocfg = pass_config(cfg, with_imu, fused)
        odo = None
        arrays, imu_batches, wheel = SensorArrays(), [], []
        offset_ns = int(round(imu_mounting[1] * 1e9)) if with_imu else 0
        early: list[ImuBatch] = []
        try:
            for rec in stream:
                if rec.kind == "imu":
                    batch: ImuBatch = rec.data
                    if gather:
                        imu_batches.append(batch)
                    if with_imu:
                        shifted = batch.shifted(offset_ns)
                        if odo is None:
                            early.append(shifted)
                        else:
                            odo.add_imu(shifted)
                elif rec.kind == "wheel":
                    wheel.append(rec.data)
                elif rec.kind == "lidar":
                    arrays.last_scan_end_ns = int(rec.data.end_ns)
                    if gather:
                        _keep_first(arrays, rec.data)
                    if span_ns is not None and until_ns is None:
                        until_ns = int(rec.data.end_ns) + span_ns
                    if until_ns is not None and rec.data.end_ns > until_ns:
                        if not gather:
                            break
                        arrays.scans += 1
                        continue
                    arrays.scans += 1
                    if odo is None:
                        arrays.lidar_frame = rec.data.frame_id
                        odo = LioOdometry(ocfg, np.eye(4), use_imu=with_imu, planar=self.planar,
                                          gyro_bias=None if not with_imu else imu_mounting[2],
                                          gyro_only=with_imu and fused is None)
                        if with_imu:
                            odo.set_imu_extrinsic(imu_mounting[0])
                            for b in early:
                                odo.add_imu(b)
                    self.pending.append(rec.data)
                if odo is not None:
                    self._process_ready(odo, rec.stamp_ns, with_imu)
            if odo is not None:
                self._process_ready(odo, None, with_imu)
        except Diverged as err:
            raise ProcessingError(f"{self.reader.path}: the LiDAR odometry behind the calibration failed: {err}") from err
        if odo is None or len(odo.poses) < 3:
            raise InputError(f"{self.reader.path}: {self.topics['lidar']}: fewer than 3 scans could be registered; "
                             "nothing to calibrate the IMU against")
        if gather:
            arrays.imu = ImuBatch.concat(imu_batches) if imu_batches else None
            arrays.imu_frame = imu_batches[0].frame_id if imu_batches else ""
            _wheel_arrays(arrays, wheel)
        self.stats = {**odo.stats.counts(), "events": len(odo.events)}
        how = "LiDAR only, no de-skew (poses at mid-sweep)"
        if with_imu:
            how = ("IMU-primed and fused" if fused else "gyro-primed") + " with the previous estimates"
        stamps = np.asarray(odo.stamps_ns, np.int64)
        if not with_imu:  # a scan registered without de-skew is where the sensor was in the middle of its sweep
            stamps = np.array([self.mid_ns.get(int(t), int(t)) for t in stamps], np.int64)
        traj = LidarTrajectory(stamps, np.asarray(odo.poses), len(odo.poses),
                               arrays.scans or self.done, f"{how}: {len(odo.poses)} of {self.done} scans")
        return traj, arrays

    def _process_ready(self, odo: LioOdometry, now_ns: int | None, with_imu: bool) -> None:
        while self.pending:
            cloud = self.pending[0]
            covered = odo.imu_until_ns()
            if with_imu and now_ns is not None and (covered is None or covered < cloud.end_ns) \
                    and now_ns - cloud.end_ns < _IMU_WAIT_NS:
                return
            self.pending.popleft()
            self.mid_ns[int(cloud.end_ns)] = (int(cloud.start_ns) + int(cloud.end_ns)) // 2
            odo.process(cloud)
            self.voxel_m = odo.voxel_size_m
            if self.sweep_voxel is not None and self.voxel_m is not None:
                self.sweeps[int(cloud.end_ns)] = thin_sweep(cloud.points, cloud.point_stamps_ns, cloud.end_ns,
                                                            self.sweep_voxel * self.voxel_m)
            self.done += 1
            if self.counter is not None:
                self.counter.step()


def _keep_first(arrays: SensorArrays, cloud: PointCloud) -> None:
    """Keep ``cloud`` (thinned) when it starts within ``FIRST_SCANS_NS`` of the first scan kept."""
    if arrays.first_scans and cloud.start_ns - arrays.first_scans[0][0] > FIRST_SCANS_NS:
        return
    step = max(1, -(-len(cloud.points) // FIRST_SCAN_POINTS))
    arrays.first_scans.append((int(cloud.start_ns), int(cloud.end_ns), np.asarray(cloud.points[::step], np.float32)))


def _wheel_arrays(arrays: SensorArrays, recs: list) -> None:
    if not recs:
        return
    s = np.array([r.stamp_ns for r in recs], np.int64)
    keep = np.concatenate([[True], np.diff(s) > 0])
    arrays.wheel_stamps_ns = s[keep]
    arrays.wheel_linear_mps = np.array([r.linear_mps[0] for r in recs])[keep]
    arrays.wheel_angular_radps = np.array([r.angular_radps[2] for r in recs])[keep]


def read_imu(reader: LogReader, topic: str) -> ImuBatch:
    """Every sample of an IMU topic (for IMU-only logs: static and Allan)."""
    imu = read_imu_topic(reader, topic)
    if not len(imu):
        raise InputError(f"{reader.path}: {topic}: no IMU sample could be read")
    return imu
