"""Where ``lio deskew`` takes the motion from, and the base's poses over one sweep from it.

Three sources, each ending in a ``PoseSpline`` of the base:
- ``trajectory``: a trajectory file or topic (``--trajectory``, e.g. lio odom's), interpolated (cubic by
  default); a sweep it does not cover (beyond 1 ms of slack at its ends) is reported, not extrapolated;
- ``imu``: lio's IMU-primed odometry run in-process (a first pass over the log) gives the corrected pose at
  every scan's end, the gyro bias and the IMU clock offset (the calibration's plus what it measured by its
  last scan); within each sweep the rotation is integrated from the gyro and the translation follows the
  cubic through the scan poses (extrapolated by at most one scan interval at the log's ends, which is how the
  first scan is covered);
- ``constant-velocity``: the same odometry LiDAR-only (constant-velocity prior and deskew), its scan poses
  interpolated as a trajectory is.
The writing pass reads the log once (``RecordFeed``): the IMU window (``ImuWindow``) reads ahead of the record
being written through the same reader, and the records it passes wait in a queue to be written in their order,
so memory holds about a second of records and IMU, not the log's.
"""

from __future__ import annotations

from collections import deque
from collections.abc import Callable, Iterator
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from ..config.deskew import DeskewConfig
from ..core.sweep_motion import PoseSpline, gyro_sweep_poses, sweep_knots
from ..errors import ConfigError, InputError
from ..geometry import inv_pose
from ..io.reader import LogReader, RawRecord, open_log
from ..io.sources import load_trajectory
from ..io.stream import SensorStream
from ..io.topics import choose_topic
from ..model.calibration import Extrinsics
from ..model.records import ImuBatch
from .odom import OdomJob, run_odom
from .odom_inputs import Mounting

_IMU_MARGIN_NS = 50_000_000  # IMU kept around a sweep for interpolation at its ends
# a trajectory is continued this far beyond its ends: a sweep sampled on the trajectory's own clock grid may
# start a few ns before it once its offsets went through a float32 time field (7.5 ns at 0.1 s)
_TRAJECTORY_SLACK_NS = 1_000_000

Progress = Callable[[int, int | None], None]


def resolve_motion(cfg: DeskewConfig, reader: LogReader) -> tuple[str, str | None]:
    """(motion source, IMU topic or None) for ``cfg`` on this log; one line (exit 2) when there is none."""
    path, motion = cfg.trajectory.path, cfg.motion
    if path is not None and motion not in ("auto", "trajectory"):
        raise ConfigError(f"--trajectory gives the motion; it cannot be combined with --motion {motion}")
    if motion == "trajectory" and path is None:
        raise ConfigError("--motion trajectory needs --trajectory FILE (TUM, e.g. from lio odom, or LOG:/topic)")
    if path is not None:
        return "trajectory", None
    if motion == "constant-velocity":
        return motion, None
    imu = choose_topic(reader, "imu", cfg.input.imu_topic, required=False).topic
    if imu is None:
        raise InputError(f"{reader.path}: no IMU topic (sensor_msgs/Imu) and no --trajectory to take the motion "
                         "from; give --trajectory FILE (e.g. from lio odom) or --motion constant-velocity for "
                         "LiDAR-only motion")
    return "imu", imu


_IMU_QUEUE_MAX = 100_000  # IMU records the window has not asked for yet (a long IMU tail after the last scan)


class RecordFeed:
    """The writing pass's records, read once from ``reader``: the writer takes them in the log's order
    (iterating the feed) while the IMU window reads ahead through ``messages``, the source ``SensorStream``
    expects. Records read ahead wait in a queue until the writer reaches them."""

    def __init__(self, reader: LogReader, imu_topic: str) -> None:
        self.reader, self.path, self._topic = reader, reader.path, imu_topic
        self._records = reader.records()
        self._ahead: deque[RawRecord] = deque()  # read, not yet written
        self._imu: deque[RawRecord] = deque()  # IMU records read, not yet given to the stream

    def _pull(self) -> RawRecord | None:
        rec = next(self._records, None)
        if rec is not None and rec.connection.topic == self._topic:
            self._imu.append(rec)
            if len(self._imu) > _IMU_QUEUE_MAX:  # no scan asked for these: older than any sweep still to come
                self._imu.popleft()
        return rec

    def __iter__(self) -> Iterator[RawRecord]:
        while True:
            rec = self._ahead.popleft() if self._ahead else self._pull()
            if rec is None:
                return
            yield rec

    def messages(self, topics=None, *, fast: bool = True) -> Iterator[tuple[str, str, int, object]]:
        """The IMU topic's messages in record order, as ``LogReader.messages(fast=True)`` gives them."""
        while True:
            while self._imu:
                rec = self._imu.popleft()
                yield rec.connection.topic, rec.connection.msgtype, rec.log_time_ns, self.reader.decode(rec)
            rec = self._pull()
            if rec is None:
                return
            self._ahead.append(rec)


class ImuWindow:
    """IMU samples around the sweep being written: read ahead through the writing pass's ``RecordFeed``
    (``attach``), else through a second reader of the same log."""

    def __init__(self, log: Path, fmt: str | None, topic: str, offset_ns: int) -> None:
        self.log, self.fmt, self.topic = log, fmt, topic
        self.reader: LogReader | None = None
        self._stream: Iterator | None = None
        self._imu = ImuBatch("", np.zeros(0, np.int64), np.zeros((0, 3)), np.zeros((0, 3)))  # samples held
        self._done = False
        self.offset_ns = offset_ns

    def attach(self, feed: RecordFeed) -> None:
        """Read the IMU from ``feed`` (before the first ``covering``)."""
        self._stream = iter(SensorStream(feed, {"imu": self.topic}, strict=False))

    def _next(self):
        if self._stream is None:
            self.reader = open_log(self.log, self.fmt)
            self._stream = iter(SensorStream(self.reader, {"imu": self.topic}, strict=False))
        return next(self._stream, None)

    def covering(self, t0_ns: int, t1_ns: int) -> ImuBatch:
        """The samples from ``t0_ns`` to ``t1_ns`` and a margin around; older ones are let go."""
        imu = self._imu
        fresh: list[ImuBatch] = []
        while not self._done:
            last = fresh[-1].stamps_ns[-1] if fresh else imu.stamps_ns[-1] if len(imu) else None
            if last is not None and last >= t1_ns + _IMU_MARGIN_NS:
                break
            rec = self._next()
            if rec is None:
                self._done = True
                break
            b: ImuBatch = rec.data
            fresh.append(ImuBatch(b.frame_id, b.stamps_ns + self.offset_ns, b.gyro_radps, b.accel_mps2))
        lo = int(np.searchsorted(imu.stamps_ns, t0_ns - _IMU_MARGIN_NS))
        if fresh or lo:  # new samples joined, old ones let go (a batch holds about two seconds)
            kept = ImuBatch(imu.frame_id, imu.stamps_ns[lo:], imu.gyro_radps[lo:], imu.accel_mps2[lo:])
            imu = self._imu = ImuBatch.concat([kept, *fresh]) if fresh else kept
            if fresh and not imu.frame_id:
                imu.frame_id = fresh[0].frame_id
        hi = int(np.searchsorted(imu.stamps_ns, t1_ns + _IMU_MARGIN_NS, side="right"))
        return ImuBatch(imu.frame_id, imu.stamps_ns[:hi], imu.gyro_radps[:hi], imu.accel_mps2[:hi])

    def close(self) -> None:
        if self.reader is not None:
            self.reader.close()


@dataclass
class Motion:
    """The base's motion from one source; ``sweep`` gives its poses over one scan."""

    source: str
    description: str
    spline: PoseSpline
    T_base_lidar: np.ndarray
    details: dict = field(default_factory=dict)  # for metrics: where it came from, the odometry's summary
    imu: ImuWindow | None = None
    gyro_bias_radps: np.ndarray | None = None
    mounting: Mounting | None = None
    imu_gap_scans: int = 0  # imu source: sweeps without IMU, interpolated from the scan poses instead
    _ext: Extrinsics | None = None

    def sweep(self, t0_ns: int, t1_ns: int, t_ref_ns: int) -> tuple[np.ndarray, np.ndarray] | str:
        """(knot stamps, T_world_base at them) over [t0, t1], or why the motion does not cover it."""
        why = self.spline.uncovered(t0_ns, t1_ns)
        if why is not None:
            return why
        if self.imu is not None:
            imu = self.imu.covering(t0_ns, t1_ns)
            if len(imu):
                if self._ext is None:  # the IMU's extrinsic by its frame id, at its first samples
                    self._ext = Extrinsics(self.mounting.resolve("T_base_imu", imu.frame_id), self.T_base_lidar)
                got = gyro_sweep_poses(self.spline, imu, t0_ns, t1_ns, t_ref_ns, self._ext, self.gyro_bias_radps)
                if got is not None:
                    return got
            self.imu_gap_scans += 1
        knots = sweep_knots(t0_ns, t1_ns)
        return knots, self.spline.at(knots)

    def close(self) -> None:
        if self.imu is not None:
            self.imu.close()


def trajectory_motion(cfg: DeskewConfig, T_base_lidar: np.ndarray) -> Motion:
    """The motion of a trajectory file or topic (of the base, or of the LiDAR with ``trajectory.frame``)."""
    tc = cfg.trajectory
    traj = load_trajectory(tc.path)
    if traj.position_only:
        raise InputError(f"{tc.path}: a GPS track has positions only; de-skewing needs orientations too")
    poses = traj.poses @ inv_pose(T_base_lidar) if tc.frame == "lidar" else traj.poses
    spline = PoseSpline(traj.stamps_ns, poses, cubic=tc.interpolation == "cubic", extrapolate_ns=_TRAJECTORY_SLACK_NS,
                        max_gap_ns=int(round(tc.max_gap_s * 1e9)))
    span = (traj.stamps_ns[-1] - traj.stamps_ns[0]) * 1e-9
    return Motion("trajectory", f"trajectory {tc.path} ({len(traj)} poses of the {tc.frame} over {span:.1f} s, "
                  f"{tc.interpolation} interpolation)", spline, T_base_lidar,
                  {"trajectory": tc.path, "poses": len(traj), "frame": tc.frame, "interpolation": tc.interpolation})


def odometry_motion(log: Path, cfg: DeskewConfig, source: str, imu_topic: str | None, mounting: Mounting,
                    T_base_lidar: np.ndarray, progress: Progress | None, reader: LogReader | None = None) -> Motion:
    """The motion of lio's odometry run in-process (IMU-primed for ``imu``, LiDAR-only for constant-velocity);
    ``reader``: the log already open."""
    result = run_odom(OdomJob(log, cfg.odom_config(source)), progress=progress, reader=reader)
    traj = result.trajectory
    stamps = traj.stamps_ns
    step = int(np.median(np.diff(stamps))) if len(stamps) > 1 else 0
    spline = PoseSpline(stamps, traj.poses, cubic=True, extrapolate_ns=step,
                        max_gap_ns=int(round(cfg.trajectory.max_gap_s * 1e9)))
    m = result.metrics
    details = {"odometry": {"scans": m["scans"], "initialisation": m["initialisation"], "fusion": m["fusion"],
                            "extrinsics": m["extrinsics"], "time_s": m["time_s"]["total"],
                            "final_gyro_bias_radps": m["final_gyro_bias_radps"]},
               "notes": list(result.notes)}
    if source == "constant-velocity":
        return Motion(source, f"LiDAR-only odometry ({len(stamps)} scan poses, constant-velocity prior), cubic "
                      "interpolation between scans", spline, T_base_lidar, details)
    bias = m["final_gyro_bias_radps"]
    if bias is None:
        cal = cfg.calibration.gyro_bias_radps
        bias = cal if cal is not None else [0.0, 0.0, 0.0]
        details["notes"].append("the odometry never started its IMU state: the gyro bias is taken as "
                                f"{'the calibration' if cal is not None else 'zero'}")
    clock = m.get("imu_time_offset")  # the calibration's offset plus what the odometry measured by its end
    offset_s = clock["estimated_s"] if clock else cfg.calibration.imu_time_offset_s
    details["imu_time_offset_s"] = offset_s
    window = ImuWindow(log, cfg.input.format, imu_topic, int(round(offset_s * 1e9)))
    return Motion("imu", f"IMU: gyro rotation within each sweep (bias from lio's IMU-primed odometry), translation "
                  f"from its {len(stamps)} scan poses", spline, T_base_lidar, details, window,
                  np.asarray(bias, dtype=np.float64), mounting)
