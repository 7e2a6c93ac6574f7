"""The ``odom`` job: read a log's stream, resolve topics and extrinsics, drive ``LioOdometry``, gather metrics.

``OdomJob`` (log + the whole configuration) is all a run needs; ``run_odom`` returns the trajectory, the
resolved configuration (topics, base frame and deskew filled in: written beside the outputs, it repeats the
run exactly), metrics and notes; ``score_odom`` adds the accuracy against a ground truth.
"""

from __future__ import annotations

import time
from collections import deque
from contextlib import nullcontext
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from ...config import with_overrides
from ...config.odom import OdomConfig
from ...core.odometry import Diverged, LioOdometry, OdomStats
from ...errors import InputError, ProcessingError
from ...io.messages.pointcloud import parse_time_convention
from ...io.logs.base import LogReader
from ...io.logs.reader import open_log
from ...io.sensors.stream import SensorStream
from ...io.sensors.tf import read_static_frames
from ...model.records import ImuBatch, PointCloud
from ...model.trajectory import Trajectory
from ..contract import score_into
from .inputs import Mounting, OdomInputs, choose_inputs

if TYPE_CHECKING:  # the evaluation and the map are loaded only by runs that score or map
    from ...evaluation.scoring import Score
    from .map import ScanSink

_IMU_WAIT_NS = 500_000_000  # a scan waits at most this long (log time) for IMU covering its end
_DOUBT_NOTE_SCANS = 5  # this many scans the IMU state could not explain, and...
_DOUBT_NOTE_SHARE = 0.02  # ...this share of the scans: a note

Progress = Callable[[int, int | None], None]  # (scans done, scans in the log or None)


@dataclass(frozen=True)
class SettledPose:
    """One scan's pose once the odometry can no longer change it (``T_world_base``, its internal world frame:
    the first scan's base, not yet levelled), with the IMU state it had then: the gyro bias (None before
    the IMU state started) and the shift the clock tracker had added to the IMU stamps."""

    stamp_ns: int
    pose: np.ndarray
    gyro_bias_radps: np.ndarray | None
    imu_shift_ns: int


PoseSink = Callable[[list[SettledPose]], None]


@dataclass(frozen=True)
class OdomJob:
    """Everything one ``lio odom`` run needs. ``map_voxel_m``: also build the map of the run (``OdomResult.map_points``)
    at this voxel size."""

    log: Path
    config: OdomConfig = field(default_factory=OdomConfig)
    map_voxel_m: float | None = None


@dataclass
class OdomResult:
    trajectory: Trajectory  # poses of the output frame at the instants the scans were de-skewed to
    config: OdomConfig  # resolved: repeats the run
    stats: OdomStats
    initialisation: str | None
    metrics: dict
    notes: list[str] = field(default_factory=list)  # warnings: things the user should fix or know
    roles: dict[str, dict] = field(default_factory=dict)  # topic taken per role, and why
    score: Score | None = None  # set by ``score_odom``
    alignment: np.ndarray | None = None  # 4x4: levels the odometry's internal world (its settled poses') frame
    map_points: np.ndarray | None = None  # (M,3) float32: the run's map in the trajectory's world (``OdomJob.map_voxel_m``)


class DivergedRun(ProcessingError):
    """The track was lost for good; ``partial`` holds the trajectory up to there (None if no scan was used)."""

    def __init__(self, message: str, partial: OdomResult | None) -> None:
        super().__init__(message)
        self.partial = partial


def run_odom(job: OdomJob, progress: Progress | None = None, reader: LogReader | None = None,
             settled: PoseSink | None = None, scans: ScanSink | None = None) -> OdomResult:
    """Run odometry over ``job.log``. ``reader``: ``job.log`` already open (a caller that reads the log again
    afterwards saves opening it twice; it stays open). ``settled``: called with each scan's ``SettledPose`` as
    soon as it is final (in order, every pose once; not the IMU predictions of
    ``registration.slow_register_every``). ``scans``: called as each scan in the map settles, with its stamp,
    pose (internal world) and de-skewed points (base frame)."""
    with nullcontext(reader) if reader is not None else open_log(job.log, job.config.input.format) as log:
        return _OdomRun(log, job.config, progress, settled, job.map_voxel_m, scans).run()


def score_odom(result: OdomResult, reference: Trajectory) -> None:
    """ATE/RPE against ``reference`` (``contract.load_reference``, read before the run) into ``result``."""
    score_into(result, reference, "odom")


class _OdomRun:
    """One pass over a log's merged stream, feeding ``LioOdometry`` in time order."""

    def __init__(self, reader: LogReader, cfg: OdomConfig, progress: Progress | None,
                 settled: PoseSink | None = None, map_voxel_m: float | None = None,
                 scans: ScanSink | None = None) -> None:
        self.reader, self.cfg, self.progress = reader, cfg, progress
        self.map = None
        if map_voxel_m or scans:
            from .map import RunMap

            self.map = RunMap(map_voxel_m, scans)
        self.settled, self.sent = settled, 0  # poses handed to ``settled`` so far
        self.t_wall = time.perf_counter()
        self.notes: list[str] = []
        self.inputs: OdomInputs = choose_inputs(reader, cfg)
        self.mounting = Mounting.of(read_static_frames(reader), cfg.calibration, cfg.input.base_frame, self.notes)
        self.odo: LioOdometry | None = None
        self.pending: deque[PointCloud] = deque()
        self.early_imu: list[ImuBatch] = []  # IMU that arrived before the first scan
        self.first_scan_ns: int | None = None  # the first scan's start, the first IMU stamp (for a late IMU's note)
        self.first_imu_ns: int | None = None
        self.t_read = 0.0
        self.done = 0

    def run(self) -> OdomResult:
        cfg, inputs = self.cfg, self.inputs
        convention = parse_time_convention(cfg.input.point_time) if cfg.input.point_time else None
        self.stream = SensorStream(self.reader, {"lidar": inputs.lidar, "imu": inputs.imu, "wheel": inputs.wheel},
                                   convention=convention, strict=False)
        try:
            self._feed()
        except Diverged as err:
            partial = self._result() if self.odo is not None and self.odo.poses else None
            raise DivergedRun(f"{self.reader.path}: {err}", partial) from err
        if not self.odo.poses:
            raise InputError(f"{self.reader.path}: {inputs.lidar}: no scan could be used (all had fewer than "
                             f"{cfg.registration.min_points} valid points)")
        self.odo.close_clock()
        self._settle(len(self.odo.poses))
        result = self._result()
        if self.map is not None:
            self.map.settle(self.odo.stamps_ns, self.odo.poses, len(self.odo.poses))
        if self.map is not None and self.map.voxels is not None:
            result.map_points = self.map.cloud(result.alignment)
            result.metrics["map"] = {"points": len(result.map_points), "voxel_m": self.map.voxel_m,
                                     "scans": self.map.scans, "frame": "the trajectory's world (levelled)"}
        return result

    def _settle(self, upto: int) -> None:
        """Hand the poses up to ``upto`` not yet handed on to the ``settled`` sink."""
        if self.settled is None or upto <= self.sent:
            return
        odo = self.odo
        bias = None if odo.state is None else odo.state.bg.copy()
        # a predicted scan's pose (``slow_register_every``) is left out: the cubic through its registered
        # neighbours is the better pose there, where its own would put the prediction's error into the velocity
        self.settled([SettledPose(int(odo.stamps_ns[i]), odo.poses[i].copy(), bias, odo.imu_shift_ns)
                      for i in range(self.sent, upto) if int(odo.stamps_ns[i]) not in odo.predicted_ns])
        self.sent = upto

    def _feed(self) -> None:
        offset_ns = self.cfg.calibration.imu_time_offset_ns
        wheel_cal = self.cfg.calibration.wheel if self.inputs.wheel else None
        if wheel_cal is not None:
            applies, said = wheel_cal.verdict(self.inputs.wheel)
            self.notes.append(f"wheel odometry {self.inputs.wheel} {said}" if applies else said)
            wheel_cal = wheel_cal if applies else None
        tick = time.process_time()
        for rec in self.stream:
            self.t_read += time.process_time() - tick
            if self.odo is None and rec.kind == "lidar":
                self._start(rec.data)
            if rec.kind == "imu":
                batch: ImuBatch = rec.data
                if offset_ns:
                    batch = batch.shifted(offset_ns)
                if self.odo is None:
                    self.early_imu.append(batch)
                else:
                    self._add_imu(batch)
            elif rec.kind == "wheel" and self.odo is not None:
                self.odo.add_wheel(rec.data if wheel_cal is None else wheel_cal.corrected(rec.data))
            elif rec.kind == "lidar":
                self.pending.append(rec.data)
            if self.odo is not None:
                self._process_ready(rec.stamp_ns)
            tick = time.process_time()
        if self.odo is None:
            raise InputError(f"{self.reader.path}: {self.inputs.lidar}: no scan with valid points in the log")
        self._process_ready(None)

    def _start(self, cloud: PointCloud) -> None:
        cal = self.cfg.calibration
        self.first_scan_ns = cloud.start_ns
        self.odo = LioOdometry(self.cfg, self.mounting.resolve("T_base_lidar", cloud.frame_id),
                               use_imu=self.inputs.use_imu, planar=self.inputs.planar,
                               gyro_bias=cal.gyro_bias_radps, accel_bias=cal.accel_bias_mps2,
                               scan_sink=None if self.map is None else self.map.scan)
        for batch in self.early_imu:
            self._add_imu(batch)

    def _add_imu(self, batch: ImuBatch) -> None:
        if self.first_imu_ns is None and len(batch):
            self.first_imu_ns = int(batch.stamps_ns[0])
        if not self.odo.imu_mounted:  # the IMU's extrinsic by its own frame_id, whenever its first message arrives
            self.odo.set_imu_extrinsic(self.mounting.resolve("T_base_imu", batch.frame_id))
        self.odo.add_imu(batch)

    def _process_ready(self, now_ns: int | None) -> None:
        odo = self.odo
        while self.pending:
            cloud = self.pending[0]
            covered = odo.imu_until_ns()
            # wait (a bounded stretch of log time) for IMU covering the scan, so its motion can be predicted
            if self.inputs.use_imu and now_ns is not None and (covered is None or covered < cloud.end_ns) \
                    and now_ns - cloud.end_ns < _IMU_WAIT_NS:
                return
            self.pending.popleft()
            odo.process(cloud)
            self._settle(odo.settled)
            if self.map is not None:
                self.map.settle(odo.stamps_ns, odo.poses, odo.settled)
            self.done += 1
            if self.progress:
                self.progress(self.done, self.reader.topics[self.inputs.lidar].count)

    def _late_imu_note(self, stamps: list[int]) -> None:
        """An IMU that starts later than the start-up window after the first scan leaves the scans before it
        LiDAR-only, with no rotation prior: say so (a walk's turns there are easily lost; a vehicle's rarely)."""
        if not self.inputs.use_imu or self.first_imu_ns is None or self.first_scan_ns is None:
            return
        lag_s = (self.first_imu_ns - self.first_scan_ns) * 1e-9
        before = int(np.searchsorted(stamps, self.first_imu_ns))  # the stamps increase
        if lag_s > self.cfg.init_window_s and before:
            note = (f"the IMU starts {lag_s:.1f} s after the first scan: the {before} scans before its first sample "
                    "are LiDAR-only (no rotation prior; fast turns there are easily lost)")
            if note not in self.notes:
                self.notes.append(note)

    def _doubt_note(self, st: OdomStats) -> None:
        """Many scans the IMU state could not explain (each placed by the LiDAR alone): an IMU clock offset beyond
        what the online estimate times, or a wrong IMU extrinsic."""
        n = st.doubted_scans
        if n >= _DOUBT_NOTE_SCANS and n >= _DOUBT_NOTE_SHARE * st.used:
            self.notes.append(
                f"the IMU prediction and the registration disagreed on {n} of {st.used} scans (those were placed by "
                "the LiDAR alone): an IMU clock offset of tens of ms or a wrong IMU extrinsic does this; measure them "
                "with lio calibrate and give --imu-time-offset or --calib")

    def _result(self) -> OdomResult:
        cfg, odo, inputs = self.cfg, self.odo, self.inputs
        wall = time.perf_counter() - self.t_wall
        stamps = odo.stamps_ns
        level = odo.output_alignment()
        P = level @ np.asarray(odo.poses)
        if cfg.frame == "lidar":
            P = P @ odo.ext.T_base_lidar
        elif cfg.frame == "imu":
            P = P @ odo.ext.T_base_imu
        resolved = with_overrides(cfg, {
            "input.lidar_topic": inputs.lidar, "input.imu_topic": inputs.imu,
            "input.wheel_topic": inputs.wheel, "input.base_frame": self.mounting.base, "deskew": inputs.deskew,
            "planar": inputs.planar,
        }, "resolved configuration")
        st = odo.stats
        start = _start_summary(odo, inputs.use_imu)
        if start.get("levelled_by") == "none" and inputs.use_imu:
            self.notes.append(f"the IMU state never started (the log is shorter than the start-up window): "
                              f"{NOT_LEVELLED}")
        self._late_imu_note(stamps)
        self._doubt_note(st)
        span_s = (stamps[-1] - stamps[0]) * 1e-9 if len(stamps) > 1 else 0.0
        metrics = {
            "log": str(self.reader.path),
            "format": self.reader.format,
            "topics": {"lidar": inputs.lidar, "imu": inputs.imu, "wheel": inputs.wheel},
            "topic_roles": inputs.describe(),
            "mode": "planar (SE(2))" if inputs.planar else "3D (SE(3))",
            "frame": cfg.frame,
            "pose_stamp": f"scan {cfg.scan_reference}: each pose is at the instant its scan was de-skewed to",
            "deskew": inputs.deskew,
            "prior": cfg.prior,
            "fusion": cfg.fusion.method if inputs.use_imu else "none (no IMU)",
            "initialisation": start["reason"],
            "initialisation_static": start["static"],
            "start": start,
            "events": odo.events,
            "imu_time_offset": _clock_summary(odo, cfg),
            "extrinsics": self.mounting.describe(),
            "scans": st.counts(),
            "stream": self.stream.stats.to_dict(),
            "voxel_size_m": odo.voxel_size_m,
            "final_gyro_bias_radps": odo.state.bg.tolist() if odo.state is not None else None,
            "final_accel_bias_mps2": odo.state.ba.tolist() if odo.state is not None else None,
            "time_s": {"read_decode": round(self.t_read, 4), **{k: round(v, 4) for k, v in st.times_s.items()},
                       "total": round(wall, 4)},
            "time_per_scan_ms": st.register_ms(),
            "trajectory_span_s": span_s,
            "real_time_factor": (span_s / wall) if wall > 0 else None,
            "notes": self.notes,
        }
        traj = Trajectory(np.asarray(stamps, dtype=np.int64), P, f"{self.reader.path}:odom", "odom")
        return OdomResult(traj, resolved, st, start["reason"], metrics, self.notes, inputs.describe(), alignment=level)


def _clock_summary(odo: LioOdometry, cfg: OdomConfig) -> dict | None:
    """The IMU clock offset used (the calibration's plus what was applied online) and as measured by the end
    (``estimated_s``: plus a residual measured too late or too small to apply)."""
    if odo.clock is None:
        return None
    given = cfg.calibration.imu_time_offset_s
    return {"calibration_s": given, "estimated_online_s": round(odo.clock.applied_s, 6),
            "total_s": round(given + odo.clock.applied_s, 6), "estimated_s": round(given + odo.clock.estimate_s, 6),
            "estimates": odo.clock.estimates}


NOT_LEVELLED = ("not levelled: the platform moved, and without the start-up window the IMU cannot tell its "
                "acceleration from gravity; the trajectory is in the first scan's base frame")


def _start_summary(odo: LioOdometry, with_imu: bool) -> dict:
    """Which start happened, after how many LiDAR-only scans, and the initial velocity (output world frame)."""
    b = odo.start
    if b is None:
        level = odo.level_source()
        reason = ("LiDAR only (no IMU in this run): level start at the origin" if not with_imu else
                  "the IMU state never started (the log is shorter than the start-up window or the IMU never "
                  "covered it): LiDAR-only scans, " + (
                      "levelled by the mean specific force (LiDAR and IMU agree the platform stood still)"
                      if level == "specific force" else NOT_LEVELLED))
        return {"kind": "lidar-only", "static": None, "scans": 0, "initial_velocity_mps": None, "reason": reason,
                "levelled_by": level}
    v = odo.output_alignment()[:3, :3] @ b.v_world
    return {"kind": "standing" if b.static else "moving", "static": b.static, "scans": b.scans,
            "initial_velocity_mps": [round(float(x), 4) for x in v], "speed_mps": round(float(np.linalg.norm(v)), 4),
            "stamp_ns": b.stamp_ns, "reason": b.reason}
