"""The first messages of a topic, as much of them as the topic and clock checks look at: header stamp,
frame ids and six numbers (an IMU's rates and accelerations, an odometry's twist).

The fixed-layout types (Imu, Odometry, TwistStamped) are read straight from their bytes with the same
header split ``series`` reads whole topics with, so a check costs no typestore decoder (rosbags compiles
one per type on its first use). A message whose length does not
fit the standard layout, and every other type, is decoded as ``LogReader.decode`` decodes it (a
PointCloud2 by lio's own parser, the rest by the typestore).
"""

from __future__ import annotations

import struct
from collections.abc import Iterator
from typing import NamedTuple

from ...errors import InputError
from ..messages.decode import IMU, ODOMETRY
from ..messages.pointcloud import stamp_to_ns
from ..messages.rawmsg import RawImu
from ..logs.base import LogReader
from ..messages.stamped_bytes import BODY_DTYPES, BULK_TYPES, split_standard


_XYZ = struct.Struct("<3d")


class Peek(NamedTuple):
    """One message as the checks see it. ``stamp_ns``: the header stamp (None for a type without a header);
    ``values``: Imu (wx, wy, wz, ax, ay, az), Odometry/TwistStamped (linear xyz, angular xyz), else ()."""

    record_ns: int
    stamp_ns: int | None
    frame_id: str
    child_frame_id: str
    values: tuple[float, ...]


def _from_bytes(raw, msgtype: str, cdr: bool) -> tuple[int, str, str, tuple[float, ...]] | None:
    buf = memoryview(raw)
    dtype = BODY_DTYPES[msgtype]
    got = split_standard(buf, cdr, msgtype == ODOMETRY, dtype.itemsize)
    if got is None:
        return None
    stamp, frame, kid, pos, _ = got
    first, second = ("w", "a") if msgtype == IMU else ("lin", "ang")
    values = _XYZ.unpack_from(buf, pos + dtype.fields[first][1]) + _XYZ.unpack_from(buf, pos + dtype.fields[second][1])
    return stamp, frame.decode(errors="replace"), kid.decode(errors="replace"), values


def _from_message(msg, msgtype: str) -> tuple[int | None, str, str, tuple[float, ...]]:
    if isinstance(msg, RawImu):  # ``LogReader.decode``'s own parse of an Imu
        return msg.stamp_ns, msg.frame_id, "", (*msg.gyro_radps, *msg.accel_mps2)
    header = getattr(msg, "header", None)
    stamp = stamp_to_ns(header.stamp) if header is not None else None
    frame = header.frame_id if header is not None else ""
    kid = getattr(msg, "child_frame_id", "") if msgtype == ODOMETRY else ""
    if msgtype == IMU:
        w, a = msg.angular_velocity, msg.linear_acceleration
        return stamp, frame, kid, (w.x, w.y, w.z, a.x, a.y, a.z)
    if msgtype in BULK_TYPES:
        tw = msg.twist.twist if msgtype == ODOMETRY else msg.twist
        return stamp, frame, kid, (tw.linear.x, tw.linear.y, tw.linear.z, tw.angular.x, tw.angular.y, tw.angular.z)
    return stamp, frame, kid, ()


def peek(log: LogReader, topic: str, n: int) -> Iterator[Peek]:
    """The first ``n`` messages of ``topic``, read one at a time as the caller asks for them (a verdict
    settled by the first message reads only that one). A damaged topic just ends the peek: it shows itself
    when it is read for real."""
    msgtype = log.topics[topic].msgtype
    cdr = log.format != "ros1"
    records = log.records([topic])
    try:
        for k, rec in enumerate(records):
            got = _from_bytes(rec.data, msgtype, cdr) if msgtype in BULK_TYPES else None
            if got is None:
                got = _from_message(log.decode(rec), msgtype)  # a cloud by lio's parser, not the typestore
            yield Peek(rec.log_time_ns, *got)
            if k + 1 >= n:
                break
    except InputError:
        return
    finally:
        records.close()


__all__ = ["Peek", "peek"]
