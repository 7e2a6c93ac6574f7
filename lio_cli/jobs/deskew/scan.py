"""One scan of ``lio deskew``: checked before the work (``plan_scans``), then de-skewed and written (``ScanWriter``).

Rules of the de-skewed cloud: same topic (or TOPIC+suffix), frame_id, fields, point order and count; x/y/z
of each valid point in the sensor frame at the reference instant (the last valid point's stamp for
``reference: end``, the first's for ``start``), which becomes the header stamp; a relative per-point time
field rewritten relative to it; invalid points untouched. A LaserScan becomes a PointCloud2 (one point per
beam, NaN for beams without a return). A scan the motion does not cover, or without a valid point, is
written unchanged and counted (``--strict``: refused).
"""

from __future__ import annotations

import time
from dataclasses import dataclass

import numpy as np

from ...config.deskew import DeskewConfig
from ...core.deskew.sweep_motion import deskew_to_sensor
from ...core.deskew.voxel_map import VoxelMap
from ...geometry import row_norms
from ...errors import InputError
from ...io.messages.cloud_rewrite import build_pointcloud2, deskewed_data, laserscan_cloud, patch_pointcloud2
from ...io.messages.decode import LASERSCAN, POINTCLOUD2
from ...io.logs.copy import LogCopy
from ...io.messages.pointcloud import (decode_laserscan, decode_pointcloud2, detect_time_convention, parse_time_convention, spins,
                             stamp_to_ns)
from ...io.messages.rawmsg import RawPointCloud2
from ...io.logs.base import LogConnection, LogReader, RawRecord
from ...io.logs.writer import LogWriter
from ...model.records import PointCloud, TimeConvention
from .motion import Motion

MAX_SWEEP_NS = 1_000_000_000  # a scan whose point times span longer is no sweep (broken or hostile times):
# copied unchanged, so its cost does not follow what its times claim


def _fmt_ns(ns: int) -> str:
    return f"{ns // 10**9}.{ns % 10**9:09d} s"


@dataclass
class ScanPlan:
    """The LiDAR topic's facts checked before any work."""

    topic: str
    msgtype: str
    out_topic: str
    frame_id: str
    forced: TimeConvention | None  # --point-time
    first: TimeConvention | None  # the first cloud's (PointCloud2)

    def describe(self) -> str:
        if self.msgtype == LASERSCAN:
            return "LaserScan: beam times from time_increment"
        conv = self.forced or self.first
        return conv.describe() + (" (as --point-time says)" if self.forced else " (detected)")


def check_convention(conv: TimeConvention, msg, cfg: DeskewConfig, where: str) -> None:
    """Refuse clouds that give no per-point time, and time fields that cannot hold the rewritten offsets."""
    names = {f.name: int(f.datatype) for f in msg.fields}
    if conv.field is None and int(msg.height) <= 1:  # first: detection also says 'none' for such clouds
        cloud = decode_pointcloud2(msg, conv)
        if not spins(cloud.points):
            raise InputError(f"{where}: clouds carry no per-point time field (fields: {', '.join(names)}) and their "
                             "points are not in a spinning sensor's firing order, so no time can be derived from "
                             "azimuth; if the time field has another name, give --point-time FIELD:UNIT")
    if conv.name == "none":
        raise InputError(f"{where}: --point-time none puts every point at the header stamp, so there is no "
                         "motion within a sweep to compensate")
    if conv.field is not None and not conv.absolute and names.get(conv.field) in (2, 4, 6) and cfg.reference == "end":
        raise InputError(f"{where}: the per-point time field '{conv.field}' is unsigned, so it cannot hold the "
                         "negative offsets of --reference end (every point before the new header stamp); "
                         "use --reference start")


def plan_scans(reader: LogReader, topic: str, cfg: DeskewConfig) -> ScanPlan:
    """Check the LiDAR topic's first scan (per-point time, time field, output topic) before any work."""
    msgtype = reader.topics[topic].msgtype
    where = f"{reader.path}: {topic}"
    out_topic = topic + cfg.topic_suffix if cfg.topic_suffix else topic
    if cfg.topic_suffix and out_topic in reader.topics:
        raise InputError(f"{where}: {out_topic} is already a topic of the log; choose another --topic-suffix")
    records = reader.records([topic])
    try:
        first = next(records)
    finally:
        records.close()
    msg = reader.decode(first)
    forced = parse_time_convention(cfg.input.point_time) if cfg.input.point_time else None
    if msgtype == LASERSCAN:
        if not float(msg.time_increment) > 0:
            raise InputError(f"{where}: LaserScan time_increment is {msg.time_increment}, so the beams carry no "
                             "time of their own and there is nothing to de-skew")
        return ScanPlan(topic, msgtype, out_topic, str(msg.header.frame_id), forced, None)
    try:
        conv = forced or detect_time_convention(msg)
        check_convention(conv, msg, cfg, where)
    except InputError as err:
        raise err if str(err).startswith(where) else InputError(f"{where}: {err}") from err
    return ScanPlan(topic, msgtype, out_topic, str(msg.header.frame_id), forced, conv)


class ScanWriter:
    """De-skews the LiDAR topic's records into the output, counting what it did."""

    def __init__(self, reader: LogReader, writer: LogWriter, copy: LogCopy, plan: ScanPlan, motion: Motion,
                 cfg: DeskewConfig, voxels: VoxelMap | None) -> None:
        self.reader, self.writer, self.copy, self.plan, self.motion = reader, writer, copy, plan, motion
        self.cfg, self.voxels = cfg, voxels
        self._out: dict[int, tuple[int, bool]] = {}  # input connection key -> (output key, re-encoded)
        self._conventions: dict[tuple, TimeConvention] = {}
        self.scans = self.deskewed = 0
        self.absurd_times = 0  # points left as they were: their time lay absurdly far from their scan's
        self.unchanged: dict[str, int] = {}
        self._shift_m: list[float] = []  # median point correction per de-skewed scan
        self._max_shift_m = 0.0
        self._times = {"decode": 0.0, "sweep_motion": 0.0, "deskew": 0.0, "encode_write": 0.0}
        self.span_ns: tuple[int, int] | None = None  # first point to last of the scans the motion was asked for

    def output(self, conn: LogConnection) -> None:
        """The output connection of one input connection of the LiDAR topic."""
        topic = self.plan.out_topic if self.cfg.topic_suffix else None
        if conn.msgtype == POINTCLOUD2:
            self._out[conn.key] = self.copy.output(conn, topic)
        else:  # a LaserScan topic becomes a PointCloud2 topic in the writer's encoding
            w = self.writer
            ros1 = w.encoding == "ros1"
            target = LogConnection(conn.key, self.plan.out_topic, POINTCLOUD2, w.encoding,
                                   callerid=conn.callerid if ros1 else None, latching=conn.latching if ros1 else None,
                                   qos=() if ros1 else conn.qos)
            self._out[conn.key] = (w.add_mirror(target), True)

    def write(self, rec: RawRecord) -> None:
        self.scans += 1
        tick = time.perf_counter()
        msg = self.reader.decode(rec)
        where = f"{self.reader.path}: {self.plan.topic}"
        try:
            if rec.connection.msgtype == LASERSCAN:
                cloud, conv = decode_laserscan(msg), None
            else:
                conv = self._convention(msg, where)
                cloud = decode_pointcloud2(msg, conv)
        except InputError as err:
            raise err if str(err).startswith(where) else InputError(f"{where}: {err}") from err
        self._times["decode"] += time.perf_counter() - tick
        self.absurd_times += cloud.bad_times
        flaw = ("no valid point" if len(cloud.points) == 0 else
                f"point times span more than {MAX_SWEEP_NS * 1e-9:g} s" if cloud.end_ns - cloud.start_ns > MAX_SWEEP_NS
                else None)
        if flaw is not None:
            if self.cfg.strict:
                raise InputError(f"{where}: the scan stamped {_fmt_ns(cloud.stamp_ns)}: {flaw}; without --strict such "
                                 "scans are copied unchanged and counted")
            return self._unchanged(rec, msg, cloud, flaw)
        t_ref = cloud.end_ns if self.cfg.reference == "end" else cloud.start_ns
        span = self.span_ns or (cloud.start_ns, cloud.end_ns)
        self.span_ns = (min(span[0], cloud.start_ns), max(span[1], cloud.end_ns))
        tick = time.perf_counter()
        got = self.motion.sweep(cloud.start_ns, cloud.end_ns, t_ref)
        self._times["sweep_motion"] += time.perf_counter() - tick
        if isinstance(got, str):
            if self.cfg.strict:
                first_ns, last_ns = self.motion.span()
                raise InputError(f"{where}: the scan of {_fmt_ns(cloud.start_ns)} to {_fmt_ns(cloud.end_ns)} is {got} "
                                 f"({_fmt_ns(first_ns)} to {_fmt_ns(last_ns)}); without --strict such scans are "
                                 "copied unchanged and counted")
            return self._unchanged(rec, msg, cloud, f"not covered by the motion: {got}")
        knots, poses = got
        tick = time.perf_counter()
        T_bl = self.motion.T_base_lidar
        xyz = deskew_to_sensor(cloud.points, cloud.point_stamps_ns, knots, poses, t_ref, T_bl)
        shift = row_norms(xyz - cloud.points)
        self._shift_m.append(float(np.median(shift)))
        self._max_shift_m = max(self._max_shift_m, float(shift.max()))
        if self.voxels is not None:
            T_wl = poses[0 if t_ref == knots[0] else -1] @ T_bl
            self.voxels.add(xyz @ T_wl[:3, :3].T + T_wl[:3, 3])
        self._times["deskew"] += time.perf_counter() - tick
        tick = time.perf_counter()
        if conv is None:
            self._emit_scan(rec, msg, xyz, t_ref)
        else:
            self._emit_cloud(rec, msg, deskewed_data(msg, conv, xyz, t_ref, cloud.kept), t_ref)
        self._times["encode_write"] += time.perf_counter() - tick
        self.deskewed += 1

    def _convention(self, msg, where: str) -> TimeConvention:
        if self.plan.forced is not None:
            return self.plan.forced
        key = tuple((f.name, int(f.datatype), int(f.offset)) for f in msg.fields)
        conv = self._conventions.get(key)
        if conv is None:  # detected once per field layout (and checked, a new layout mid-log too)
            conv = self._conventions[key] = detect_time_convention(msg)
            check_convention(conv, msg, self.cfg, where)
        return conv

    def _emit_cloud(self, rec: RawRecord, msg, data: np.ndarray, stamp_ns: int) -> None:
        key, recoded = self._out[rec.connection.key]
        out = None
        if not recoded and isinstance(msg, RawPointCloud2):
            out = patch_pointcloud2(rec.data, msg, data, stamp_ns, rec.connection.encoding)
        if out is None:
            if not recoded and rec.connection.encoding != self.writer.encoding:
                raise InputError(f"{self.reader.path}: {rec.connection.topic}: cannot re-encode a non-standard "
                                 f"{rec.connection.encoding} PointCloud2 in {self.writer.format}; write --format ros1")
            out = self.writer.serialize(build_pointcloud2(self.writer.make, msg, data, stamp_ns), POINTCLOUD2)
        self.writer.write_record(key, rec.log_time_ns, out, rec.publish_time_ns, rec.sequence)

    def _emit_scan(self, rec: RawRecord, msg, xyz: np.ndarray, stamp_ns: int) -> None:
        key, _ = self._out[rec.connection.key]
        arr = laserscan_cloud(msg, xyz, stamp_ns)
        out = self.writer.serialize(self.writer.make.pointcloud2(stamp_ns, str(msg.header.frame_id), arr), POINTCLOUD2)
        self.writer.write_record(key, rec.log_time_ns, out, rec.publish_time_ns, rec.sequence)

    def _unchanged(self, rec: RawRecord, msg, cloud: PointCloud, reason: str) -> None:
        """The scan as it came (a LaserScan as a cloud with its own header stamp), counted with ``reason``."""
        self.unchanged[reason] = self.unchanged.get(reason, 0) + 1
        if rec.connection.msgtype == LASERSCAN:
            return self._emit_scan(rec, msg, cloud.points, stamp_to_ns(msg.header.stamp))
        key, recoded = self._out[rec.connection.key]
        data = self.copy.convert(rec) if recoded else rec.data
        self.writer.write_record(key, rec.log_time_ns, data, rec.publish_time_ns, rec.sequence)

    def summary(self) -> dict:
        shifts = np.asarray(self._shift_m)
        return {"scans": {"total": self.scans, "deskewed": self.deskewed, "unchanged": sum(self.unchanged.values()),
                          "unchanged_why": dict(self.unchanged)},
                "points_with_absurd_time_left_unchanged": self.absurd_times,
                "correction_m": {"median_of_scan_medians": round(float(np.median(shifts)), 5) if len(shifts) else None,
                                 "p95_of_scan_medians": round(float(np.percentile(shifts, 95)), 5) if len(shifts) else None,
                                 "max": round(self._max_shift_m, 5),
                                 "meaning": "how far de-skewing moved the points (sensor frame)"}}

    def times(self) -> dict:
        return {k: round(v, 4) for k, v in self._times.items()}
