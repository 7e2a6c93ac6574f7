"""Where ``lio deskew`` takes the motion from, and the base's poses over one sweep from it.

Three sources, each ending in a ``PoseSpline`` of the base:
- ``trajectory``: a trajectory file or topic (``--trajectory``, e.g. lio odom's), interpolated (cubic by
  default); a sweep it does not cover (beyond 1 ms of slack at its ends) is reported, not extrapolated;
- ``imu``: lio's IMU-primed odometry (a first pass over the log, in this process or beside the writing pass:
  ``deskew_helper``) gives the corrected pose at every scan's end with the gyro bias and IMU clock offset it
  had once that pose was final (``PoseFeed``); within each sweep the rotation is integrated from the gyro with them and the
  translation follows the cubic through the scan poses (extrapolated by at most one scan interval at the
  log's ends, which is how the first scan is covered);
- ``constant-velocity``: the same odometry LiDAR-only (constant-velocity prior and deskew), its scan poses
  interpolated as a trajectory is.
The writing pass reads the log once (``RecordFeed``): the IMU window (``ImuWindow``) reads ahead of the record
being written through the same reader, and the records it passes wait in a queue to be written in their order,
so memory holds about a second of records and IMU, not the log's.
"""

from __future__ import annotations

from collections import deque
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ...config.deskew import DeskewConfig
from ...core.deskew.sweep_motion import PoseSpline, gyro_sweep_poses, sweep_knots
from ...errors import ConfigError, InputError
from ...geometry import inv_pose
from ...io.logs.base import LogReader, RawRecord
from ...io.logs.reader import open_log
from ...io.sensors.sources import load_trajectory
from ...io.sensors.stream import SensorStream
from ...io.sensors.topics import choose_topic, unpublished
from ...model.calibration import Extrinsics
from ...model.records import ImuBatch, on_lidar_clock
from .poses import OFFSET_AGREE_NS, PoseFeed
from ..odom.job import OdomJob, SettledPose, run_odom
from ..odom.inputs import Mounting

_IMU_MARGIN_NS = 50_000_000  # IMU kept around a sweep for interpolation at its ends
# a trajectory is continued this far beyond its ends: a sweep sampled on the trajectory's own clock grid may
# start a few ns before it once its offsets went through a float32 time field (7.5 ns at 0.1 s)
_TRAJECTORY_SLACK_NS = 1_000_000
_TRAJECTORY_MAX_EXTEND_NS = 200_000_000  # beyond a trajectory's ends: at most one pose interval, and never more than this
_OTHER_CLOCK_NS = 60_000_000_000  # a trajectory this far from every scan belongs to another clock

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
        raise InputError(f"{reader.path}: no IMU topic (sensor_msgs/Imu){unpublished(reader, 'imu')} and no "
                         "--trajectory to take the motion "
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
    (``attach``), else through a second reader of the same log. Held on the IMU's own clock; ``covering``
    moves them by the offset of the sweep asked for."""

    def __init__(self, log: Path, fmt: str | None, topic: str) -> None:
        self.log, self.fmt, self.topic = log, fmt, topic
        self.reader: LogReader | None = None
        self._stream: Iterator | None = None
        self._imu = ImuBatch("", np.zeros(0, np.int64), np.zeros((0, 3)), np.zeros((0, 3)))  # samples held
        self._done = False

    def attach(self, feed: RecordFeed) -> None:
        """Read the IMU from ``feed`` (before the first ``covering``)."""
        self._stream = iter(SensorStream(feed, {"imu": self.topic}, strict=False))

    def _next(self):
        if self._stream is None:
            self.reader = open_log(self.log, self.fmt)
            self._stream = iter(SensorStream(self.reader, {"imu": self.topic}, strict=False))
        return next(self._stream, None)

    def covering(self, t0_ns: int, t1_ns: int, offset_ns: int) -> ImuBatch:
        """The samples from ``t0_ns`` to ``t1_ns`` (LiDAR clock; IMU stamps + ``offset_ns``) and a margin
        around, on the LiDAR's clock; older ones are let go."""
        t0_ns, t1_ns = t0_ns - offset_ns, t1_ns - offset_ns  # on the IMU's clock
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
            fresh.append(rec.data)
        lo = int(np.searchsorted(imu.stamps_ns, t0_ns - _IMU_MARGIN_NS))
        if fresh or lo:  # new samples joined, old ones let go (a batch holds about two seconds)
            kept = ImuBatch(imu.frame_id, imu.stamps_ns[lo:], imu.gyro_radps[lo:], imu.accel_mps2[lo:])
            imu = self._imu = ImuBatch.concat([kept, *fresh]) if fresh else kept
            if fresh and not imu.frame_id:
                imu.frame_id = fresh[0].frame_id
        hi = int(np.searchsorted(imu.stamps_ns, t1_ns + _IMU_MARGIN_NS, side="right"))
        return ImuBatch(imu.frame_id, on_lidar_clock(imu.stamps_ns[:hi], offset_ns), imu.gyro_radps[:hi],
                        imu.accel_mps2[:hi])

    def close(self) -> None:
        if self.reader is not None:
            self.reader.close()


@dataclass
class Motion:
    """The base's motion from one source; ``sweep`` gives its poses over one scan. ``spline``: the whole
    trajectory (trajectory source), else ``feed``: the odometry's poses as they settle."""

    T_base_lidar: np.ndarray
    spline: PoseSpline | None = None
    feed: PoseFeed | None = None
    imu: ImuWindow | None = None
    mounting: Mounting | None = None
    imu_gap_scans: int = 0  # imu source: sweeps without IMU, interpolated from the scan poses instead
    _ext: Extrinsics | None = None

    def span(self) -> tuple[int, int]:
        """(first, last) instant of the poses, for messages."""
        if self.spline is not None:
            return self.spline.first_ns, self.spline.last_ns
        return self.feed.first_ns or 0, self.feed.last_ns or 0

    def sweep(self, t0_ns: int, t1_ns: int, t_ref_ns: int) -> tuple[np.ndarray, np.ndarray] | str:
        """(knot stamps, T_world_base at them) over [t0, t1], or why the motion does not cover it."""
        spline = self.spline if self.spline is not None else self.feed.spline(t0_ns, t1_ns)
        if isinstance(spline, str):
            return spline
        why = spline.uncovered(t0_ns, t1_ns)
        if why is not None:
            return why
        if self.imu is not None:
            bias, offset_ns = self.feed.imu_state(t_ref_ns)
            imu = self.imu.covering(t0_ns, t1_ns, offset_ns)
            if len(imu):
                if self._ext is None:  # the IMU's extrinsic by its frame id, at its first samples
                    self._ext = Extrinsics(self.mounting.resolve("T_base_imu", imu.frame_id), self.T_base_lidar)
                got = gyro_sweep_poses(spline, imu, t0_ns, t1_ns, t_ref_ns, self._ext, bias)
                if got is not None:
                    return got
            self.imu_gap_scans += 1
        knots = sweep_knots(t0_ns, t1_ns)
        return knots, spline.at(knots)

    def close(self) -> None:
        if self.imu is not None:
            self.imu.close()


def trajectory_motion(cfg: DeskewConfig, T_base_lidar: np.ndarray) -> tuple[Motion, str, dict]:
    """The motion of a trajectory file or topic (of the base, or of the LiDAR with ``trajectory.frame``), its
    description and details."""
    tc = cfg.trajectory
    traj = load_trajectory(tc.path)
    if traj.position_only:
        raise InputError(f"{tc.path}: a GPS track has positions only; de-skewing needs orientations too")
    poses = traj.poses @ inv_pose(T_base_lidar) if tc.frame == "lidar" else traj.poses
    # a sweep up to one pose interval beyond either end is covered by the end segment's velocity: lio odom stamps
    # each pose at its scan's end, so its first scan begins a whole interval before the trajectory does
    step_ns = int(np.median(np.diff(traj.stamps_ns))) if len(traj) > 1 else 0
    slack_ns = min(max(step_ns, _TRAJECTORY_SLACK_NS), _TRAJECTORY_MAX_EXTEND_NS)
    spline = PoseSpline(traj.stamps_ns, poses, cubic=tc.interpolation == "cubic", extrapolate_ns=slack_ns,
                        max_gap_ns=int(round(tc.max_gap_s * 1e9)))
    span = (traj.stamps_ns[-1] - traj.stamps_ns[0]) * 1e-9
    return (Motion(T_base_lidar, spline=spline),
            f"trajectory {tc.path} ({len(traj)} poses of the {tc.frame} over {span:.1f} s, {tc.interpolation} "
            "interpolation)",
            {"trajectory": tc.path, "poses": len(traj), "frame": tc.frame, "interpolation": tc.interpolation})


def check_covered(stats: dict, motion: Motion, path: str, topic: str) -> None:
    """Refuse a trajectory that covers none of the scans (before anything is renamed into place): the run would
    be a copy of the log. Far apart, it is on another clock (a TUM from 0 beside a log in epoch time)."""
    scans, span = stats["scans"], stats.get("scan_span_ns")
    if scans["deskewed"] or span is None or not any(w.startswith("not covered") for w in scans["unchanged_why"]):
        return
    first, last = motion.span()
    apart = max(span[0] - last, first - span[1])
    why = (f": {apart * 1e-9:.6g} s apart, it looks stamped on another clock" if apart > _OTHER_CLOCK_NS
           else "")
    raise InputError(f"{path}: the trajectory ({_fmt_s(first)}..{_fmt_s(last)} s) covers none of the "
                     f"{scans['total']} scans of {topic} ({_fmt_s(span[0])}..{_fmt_s(span[1])} s){why}")


def _fmt_s(ns: int) -> str:
    return f"{ns * 1e-9:.3f}"


def settled_motion(log: Path, cfg: DeskewConfig, source: str, imu_topic: str | None, mounting: Mounting,
                   T_base_lidar: np.ndarray, batches: Iterator[list[SettledPose]],
                   final_offset_ns: int | None = None) -> Motion:
    """The motion of lio's odometry (IMU-primed for ``imu``, LiDAR-only for constant-velocity) from its settled
    poses, ``batches`` as they come (``final_offset_ns``: see ``PoseFeed``)."""
    cal = cfg.calibration
    bias = np.asarray(cal.gyro_bias_radps if cal.gyro_bias_radps is not None else [0.0, 0.0, 0.0], dtype=np.float64)
    feed = PoseFeed(batches, max_gap_ns=int(round(cfg.trajectory.max_gap_s * 1e9)), offset_ns=cal.imu_time_offset_ns,
                    default_bias=bias, final_offset_ns=final_offset_ns)
    imu = ImuWindow(log, cfg.input.format, imu_topic) if source == "imu" else None
    return Motion(T_base_lidar, feed=feed, imu=imu, mounting=mounting)


@dataclass
class OdometryMotion:
    """What the odometry's run says of the motion: for metrics, and the two numbers the writing needs."""

    description: str
    details: dict
    notes: list[str]
    level: np.ndarray  # the rotation (4x4) that levels the odometry's world frame: the map's
    final_offset_ns: int | None  # the IMU clock offset for every scan (see PoseFeed), or None: as applied
    batches: list[list[SettledPose]]  # the settled poses, as they were handed on


def run_odometry(log: Path, cfg: DeskewConfig, source: str, progress: Progress | None, reader: LogReader | None,
                 settled: Callable[[list[SettledPose]], None] | None = None) -> OdometryMotion:
    """Run lio's odometry for the motion, handing its settled poses on to ``settled`` as they come."""
    batches: list[list[SettledPose]] = []

    def sink(batch: list[SettledPose]) -> None:
        batches.append(batch)
        if settled is not None:
            settled(batch)

    result = run_odom(OdomJob(log, cfg.odom_config(source)), progress=progress, reader=reader, settled=sink)
    traj, m = result.trajectory, result.metrics
    level = result.alignment
    details = {"odometry": {"scans": m["scans"], "initialisation": m["initialisation"], "fusion": m["fusion"],
                            "extrinsics": m["extrinsics"], "time_s": m["time_s"]["total"],
                            "final_gyro_bias_radps": m["final_gyro_bias_radps"]}}
    notes = list(result.notes)
    n = len(traj)
    if source == "constant-velocity":
        return OdometryMotion(f"LiDAR-only odometry ({n} scan poses, constant-velocity prior), cubic interpolation "
                              "between scans", details, notes, level, None, batches)
    if m["final_gyro_bias_radps"] is None:
        cal = cfg.calibration.gyro_bias_radps
        notes.append("the odometry never started its IMU state: the gyro bias is taken as "
                     f"{'the calibration' if cal is not None else 'zero'}")
    clock, given_ns = m.get("imu_time_offset"), cfg.calibration.imu_time_offset_ns
    final_ns = int(round(clock["estimated_s"] * 1e9)) if clock else given_ns
    if max(abs(given_ns + p.imu_shift_ns - final_ns) for b in batches for p in b) > OFFSET_AGREE_NS:
        details["imu_time_offset_s"] = final_ns * 1e-9
        details["imu_time_offset"] = "the odometry's final estimate, for every scan (it moved its offset online)"
        return OdometryMotion(f"IMU: gyro rotation within each sweep (bias as lio's IMU-primed odometry had it at "
                              f"that scan, clock offset as it measured by its end), translation from its {n} scan "
                              "poses", details, notes, level, final_ns, batches)
    details["imu_time_offset_s"] = clock["total_s"] if clock else cfg.calibration.imu_time_offset_s
    details["imu_time_offset"] = f"as the odometry applied it at each scan (within {OFFSET_AGREE_NS / 1e6:g} ms of its final estimate)"
    return OdometryMotion(f"IMU: gyro rotation within each sweep (bias and clock offset as lio's IMU-primed odometry "
                          f"had them at that scan), translation from its {n} scan poses", details, notes, level, None, batches)
