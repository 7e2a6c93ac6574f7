"""What a log holds: topics, rates, cloud layout and per-point time convention, static frames.

``describe_log`` reads the log's index plus the first message of each scan topic and /tf_static, so it
stays quick on long logs; ``check_log`` decodes every sensor message for a full validation.
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np

from ..errors import InputError
from ..geometry import pose_to_xyz_quat, so3_log
from ..io.messages.decode import KIND_TYPES, POINTCLOUD2
from ..io.messages.pointcloud import decode_laserscan, decode_pointcloud2, detect_time_convention
from ..io.logs.base import LogReader
from ..io.sensors.stream import SensorStream
from ..io.sensors.tf import read_static_frames
from ..model.records import TimeConvention

_TYPE_NAMES = {1: "int8", 2: "uint8", 3: "int16", 4: "uint16", 5: "int32", 6: "uint32", 7: "float32", 8: "float64"}


def _first_message(log: LogReader, topic: str):
    messages = log.messages([topic])
    try:
        for _, _, _, msg in messages:
            return msg
        return None
    finally:
        messages.close()  # release the reader's cursor now, not at garbage collection


def describe_scan_topic(log: LogReader, topic: str, convention: TimeConvention | None = None) -> dict:
    """Fields, point count and per-point time convention of a scan topic, from its first message."""
    info = log.topics[topic]
    msg = _first_message(log, topic)
    out: dict = {"topic": topic, "type": info.msgtype}
    if msg is None:
        return out
    try:
        return _describe_scan(msg, info.msgtype, out, convention)
    except InputError as err:
        raise InputError(f"{log.path}: {topic}: {err}") from err


def _describe_scan(msg, msgtype: str, out: dict, convention: TimeConvention | None) -> dict:
    if msgtype == POINTCLOUD2:
        conv = convention or detect_time_convention(msg)
        cloud = decode_pointcloud2(msg, conv)
        out["fields"] = [
            {"name": f.name, "type": _TYPE_NAMES.get(int(f.datatype), str(f.datatype)), "offset": int(f.offset),
             "count": int(f.count)} for f in msg.fields
        ]
        out["point_step"] = int(msg.point_step)
        out["height"], out["width"] = int(msg.height), int(msg.width)
        out["big_endian"] = bool(msg.is_bigendian)
    else:
        cloud = decode_laserscan(msg)
        conv = cloud.convention
        out["beams"] = len(msg.ranges)
    out["frame_id"] = cloud.frame_id
    out["points"] = int(len(cloud.points) + cloud.dropped)
    out["valid_points"] = int(len(cloud.points))
    out["time_convention"] = {
        "name": conv.name,
        "field": conv.field,
        "absolute": conv.absolute,
        "description": conv.describe(),
        "header_stamp_marks": cloud.header_marks,
    }
    if len(cloud.point_stamps_ns):
        out["time_convention"]["scan_duration_s"] = (cloud.end_ns - cloud.start_ns) * 1e-9
    return out


def describe_log(log: LogReader, convention: TimeConvention | None = None) -> dict:
    """A summary of the log as a JSON-able dict (the data behind ``lio info``).

    An empty log (no messages at all) is bad input: ``InputError``.
    """
    if not any(t.count for t in log.topics.values()):
        what = f"{len(log.topics)} topic(s) but" if log.topics else "no topics and"
        raise InputError(f"{log.path}: empty log ({what} 0 messages); nothing to read, check the recording")
    topics = []
    for name in sorted(log.topics):
        t = log.topics[name]
        topics.append({"topic": name, "type": t.msgtype, "count": t.count,
                       "rate_hz": round(t.rate_hz, 3) if t.rate_hz else None})
    scans = [describe_scan_topic(log, name, convention) for name in sorted(log.topics)
             if log.topics[name].msgtype in KIND_TYPES["lidar"] and log.topics[name].count > 0]
    tree = read_static_frames(log)
    frames = []
    for tr in tree.transforms:
        xyz, q = pose_to_xyz_quat(tr.pose)
        frames.append({"parent": tr.parent, "child": tr.child, "xyz_m": xyz.round(6).tolist(),
                       "quat_xyzw": q.round(9).tolist(),
                       "angle_deg": round(float(np.degrees(np.linalg.norm(so3_log(tr.pose[:3, :3])))), 4)})
    return {
        "path": str(log.path),
        "format": log.format,
        "start_ns": log.start_ns,
        "end_ns": log.end_ns,
        "start_utc": utc_date(log.start_ns),
        "end_utc": utc_date(log.end_ns),
        "duration_s": log.duration_ns * 1e-9,
        "messages": sum(t.count for t in log.topics.values()),
        "topics": topics,
        "scans": scans,
        "static_transforms": frames,
        "static_transform_problems": [c["message"] for c in tree.conflicts] + tree.warnings,
        "frames": tree.frames,
    }


EPOCH_FROM_NS = 946_684_800 * 10**9  # 2000-01-01: an earlier stamp is a clock since boot or simulation start


def utc_date(ns: int | None) -> str | None:
    """``ns`` as an ISO 8601 UTC date to the millisecond, or None when it cannot be a date (before 2000)."""
    if ns is None or ns < EPOCH_FROM_NS:
        return None
    import datetime as dt

    t = dt.datetime.fromtimestamp(ns // 10**9, dt.timezone.utc)
    return f"{t:%Y-%m-%dT%H:%M:%S}.{ns % 10**9 // 10**6:03d}Z"


def check_log(log: LogReader, convention: TimeConvention | None = None,
              progress: Callable[[float], None] | None = None) -> dict:
    """Decode every sensor message (scans, IMU, odometry, poses); raises InputError on the first bad one.

    A /tf_static that contradicts itself (a cycle whose chains disagree) fails the check too."""
    tree = read_static_frames(log)
    if tree.conflicts:
        raise InputError(tree.conflicts[0]["message"])
    topics_by_kind: dict[str, list[str]] = {}
    for name, t in log.topics.items():
        for kind, types in KIND_TYPES.items():
            if t.msgtype in types:
                topics_by_kind.setdefault(kind, []).append(name)
                break
    checked: dict[str, int] = {}
    for kind, names in topics_by_kind.items():
        for name in names:
            stream = SensorStream(log, {kind: name}, convention=convention, strict=True)
            n = 0
            for rec in stream:
                k = len(rec.data) if kind == "imu" else 1
                n += k
                if progress:
                    progress(k)
            checked[name] = n
    if not sum(checked.values()):
        kinds = "PointCloud2, LaserScan, Imu, Odometry or pose"
        raise InputError(f"{log.path}: nothing checkable: not one {kinds} message decoded "
                         f"({len(log.topics)} topic(s) of other types), so --check cannot pass")
    return {"checked": checked}
