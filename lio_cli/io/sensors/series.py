"""Whole topics of small messages (Imu, Odometry, TwistStamped, PoseStamped, TransformStamped) as column arrays.

A fusion run reads every message of a few small topics, and decoding them one typestore object at a time
costs as much as the estimation. Here the fixed-layout types (Imu, Odometry, TwistStamped) are read from
their bytes: each message's header (stamp, frame ids) with ``struct``, its fixed-size body sliced off, and
the bodies of a whole topic parsed in one numpy call. A message whose length does not fit the standard
layout (another definition of the type, big-endian CDR, damage) sends its topic through the typestore
instead, which also reports real corruption as ``InputError``. Nothing is filtered here: NaN, zero
quaternions, covariances of 0 or -1, duplicated and out-of-order stamps arrive as recorded (the fusion
core counts and handles them).
"""

from __future__ import annotations

import struct
from collections.abc import Callable, Iterable
from dataclasses import dataclass

import numpy as np

from ...errors import InputError
from ..messages.decode import IMU, ODOMETRY, POSE_STAMPED, TRANSFORM_STAMPED, TWIST_STAMPED
from .imu_units import accel_scale
from ..logs.base import LogReader
from ..messages.stamped_bytes import BODY_DTYPES, split_header, split_standard

POSE_TYPES = (ODOMETRY, POSE_STAMPED, TRANSFORM_STAMPED)

_PROGRESS_EVERY = 4096

Progress = Callable[[int], None]  # messages read so far


@dataclass
class ImuColumns:
    """Every message of one Imu topic, in record order. ``orientation_cov`` (N,9) row-major, as ROS writes it."""

    topic: str
    frame_id: str
    stamps_ns: np.ndarray
    gyro_radps: np.ndarray
    accel_mps2: np.ndarray
    quat_xyzw: np.ndarray
    orientation_cov: np.ndarray
    frames: tuple[str, ...] = ()  # every frame id seen

    def __len__(self) -> int:
        return len(self.stamps_ns)


@dataclass
class MotionColumns:
    """Every message of one Odometry, TwistStamped, PoseStamped or TransformStamped topic, in record order.

    Pose fields are NaN for TwistStamped, twist fields NaN for PoseStamped/TransformStamped; covariances
    (N,36) row-major (None when the type has none)."""

    topic: str
    msgtype: str
    frame_id: str
    child_frame_id: str
    stamps_ns: np.ndarray
    position_m: np.ndarray
    quat_xyzw: np.ndarray
    pose_cov: np.ndarray | None
    linear_mps: np.ndarray
    angular_radps: np.ndarray
    twist_cov: np.ndarray | None

    def __len__(self) -> int:
        return len(self.stamps_ns)


class _Bulk:
    """Headers and bodies of one topic's messages, collected while the log is read."""

    def __init__(self, msgtype: str, cdr: bool) -> None:
        self.msgtype, self.cdr = msgtype, cdr
        self.size = BODY_DTYPES[msgtype].itemsize
        self.child = msgtype == ODOMETRY
        self.stamps: list[int] = []
        self.bodies: list = []
        self.frames: dict[bytes, None] = {}
        self.kids: dict[bytes, None] = {}
        self.ok = True
        self.raws: list = []  # ROS 1 messages kept for ``finish`` (the whole topic parsed at once where it can be)
        self._body: np.ndarray | None = None  # set by a whole-topic parse

    def finish(self) -> None:
        raws, self.raws = self.raws, []
        if not (raws and self._add_uniform(raws)):
            for raw in raws:
                self.add(raw)

    def _add_uniform(self, raws: list) -> bool:
        """ROS 1 messages all of one length with one frame id (and child frame id): headers and bodies of the
        whole topic parsed by one numpy structured dtype, the same fields ``add`` reads one message at a
        time. False (nothing added) when the topic is not that uniform."""
        first = memoryview(raws[0])
        try:
            _, frame, kid, pos = split_header(first, False, self.child)
        except (struct.error, ValueError, IndexError):
            return False
        size = len(first)
        if pos + self.size != size or any(len(r) != size for r in raws):
            return False
        fields = [("seq", "<u4"), ("sec", "<u4"), ("nsec", "<u4"), ("flen", "<u4"), ("frame", "u1", (len(frame),))]
        if self.child:
            fields += [("klen", "<u4"), ("kid", "u1", (len(kid),))]
        fields.append(("body", BODY_DTYPES[self.msgtype]))
        dtype = np.dtype(fields)
        if dtype.itemsize != size:
            return False
        arr = np.frombuffer(b"".join(raws), dtype=dtype)
        if np.any(arr["flen"] != len(frame)) or np.any(arr["frame"] != np.frombuffer(frame, np.uint8)):
            return False
        if self.child and (np.any(arr["klen"] != len(kid)) or np.any(arr["kid"] != np.frombuffer(kid, np.uint8))):
            return False
        self.stamps = arr["sec"].astype(np.int64) * 1_000_000_000 + arr["nsec"]  # as read_series hands them on
        self._body = arr["body"]  # a view: the columns are copied out of it (a structured copy is slow)
        self.frames.setdefault(frame)
        if self.child:
            self.kids.setdefault(kid)
        return True

    def add(self, raw) -> None:
        if not self.ok:
            return
        buf = memoryview(raw)
        got = split_standard(buf, self.cdr, self.child, self.size)
        if got is None:
            self.ok = False  # not the standard layout: the typestore reads this topic
            self.bodies = []
            return
        stamp, frame, kid, pos, self.cdr = got
        self.stamps.append(stamp)
        self.bodies.append(bytes(buf[pos:]))  # a copy: a view would keep the whole chunk alive
        self.frames.setdefault(frame)
        if self.child:
            self.kids.setdefault(kid)

    def body(self) -> np.ndarray:
        if self._body is not None:
            return self._body
        return np.frombuffer(b"".join(self.bodies), dtype=BODY_DTYPES[self.msgtype])

    def frame_ids(self) -> tuple[str, ...]:
        return tuple(f.decode(errors="replace") for f in self.frames)

    def child_ids(self) -> tuple[str, ...]:
        return tuple(f.decode(errors="replace") for f in self.kids)


def read_series(log: LogReader, topics: Iterable[str], progress: Progress | None = None
                ) -> dict[str, ImuColumns | MotionColumns]:
    """Every message of ``topics`` (Imu, Odometry, TwistStamped, PoseStamped, TransformStamped) as columns,
    in one pass over the log (plus one typestore pass per topic that needs it)."""
    topics = list(dict.fromkeys(topics))
    bulk: dict[str, _Bulk] = {}
    slow: list[str] = []
    for t in topics:
        msgtype = log.topics[t].msgtype
        if msgtype in BODY_DTYPES:
            bulk[t] = _Bulk(msgtype, log.format != "ros1")
        elif msgtype in (POSE_STAMPED, TRANSFORM_STAMPED):
            slow.append(t)
        else:
            raise InputError(f"{log.path}: topic {t} is {msgtype}, which fuse cannot read")
    if bulk:
        # a ROS 1 bag's topics are handed over whole for ``finish`` to parse; others are parsed as read
        by_topic = log.topic_messages(list(bulk), progress)
        if by_topic is not None:  # a ROS 1 bag's topics handed over whole
            for t, raws in by_topic.items():
                bulk[t].raws = raws
        else:
            keep = {t: b.add if b.cdr else b.raws.append for t, b in bulk.items()}
            for n, (topic, _, _, raw) in enumerate(log.raw_messages(list(bulk)), 1):
                keep[topic](raw)
                if progress is not None and n % _PROGRESS_EVERY == 0:
                    progress(n)
        for b in bulk.values():
            b.finish()
    out: dict[str, ImuColumns | MotionColumns] = {}
    for t, b in bulk.items():
        if b.ok:
            out[t] = _imu_from_bulk(t, b) if b.msgtype == IMU else _motion_from_bulk(t, b)
        else:
            slow.append(t)
    for t in slow:
        out[t] = _read_typestore(log, t)
    for t, cols in out.items():
        if isinstance(cols, ImuColumns):
            cols.accel_mps2 *= accel_scale(log, t)[0]  # an IMU writing g (Livox): to m/s^2
    return {t: out[t] for t in topics}


def _imu_from_bulk(topic: str, b: _Bulk) -> ImuColumns:
    body = b.body()
    frames = b.frame_ids()
    return ImuColumns(topic, frames[0] if frames else "", np.asarray(b.stamps, np.int64), body["w"].copy(),
                      body["a"].copy(), body["q"].copy(), body["qcov"].copy(), frames)


def _nan(n: int, k: int) -> np.ndarray:
    return np.full((n, k), np.nan)


def _motion_from_bulk(topic: str, b: _Bulk) -> MotionColumns:
    body = b.body()
    n = len(body)
    frames, kids = b.frame_ids(), b.child_ids()
    frame = frames[0] if frames else ""
    if b.msgtype == ODOMETRY:
        return MotionColumns(topic, b.msgtype, frame, kids[0] if kids else "", np.asarray(b.stamps, np.int64),
                             body["p"].copy(), body["q"].copy(), body["pcov"].copy(), body["lin"].copy(),
                             body["ang"].copy(), body["tcov"].copy())
    return MotionColumns(topic, b.msgtype, frame, frame, np.asarray(b.stamps, np.int64), _nan(n, 3), _nan(n, 4),
                         None, body["lin"].copy(), body["ang"].copy(), None)


def _xyz(v) -> tuple[float, float, float]:
    return v.x, v.y, v.z


def _read_typestore(log: LogReader, topic: str) -> ImuColumns | MotionColumns:
    """The same columns through the typestore (any definition or encoding the reader understands)."""
    from ..messages.pointcloud import stamp_to_ns

    msgtype = log.topics[topic].msgtype
    rows = []
    frame = child = ""
    for _, _, _, m in log.messages([topic]):
        if not rows:
            frame = m.header.frame_id
            child = getattr(m, "child_frame_id", "") if msgtype in (ODOMETRY, TRANSFORM_STAMPED) else frame
        st = stamp_to_ns(m.header.stamp)
        if msgtype == IMU:
            o = m.orientation
            rows.append((st, _xyz(m.angular_velocity), _xyz(m.linear_acceleration), (o.x, o.y, o.z, o.w),
                         tuple(np.asarray(m.orientation_covariance, float).reshape(9))))
        elif msgtype == ODOMETRY:
            p, tw = m.pose.pose, m.twist.twist
            o = p.orientation
            rows.append((st, _xyz(p.position), (o.x, o.y, o.z, o.w), np.asarray(m.pose.covariance, float),
                         _xyz(tw.linear), _xyz(tw.angular), np.asarray(m.twist.covariance, float)))
        elif msgtype == TWIST_STAMPED:
            rows.append((st, _xyz(m.twist.linear), _xyz(m.twist.angular)))
        else:
            tr = m.transform if msgtype == TRANSFORM_STAMPED else m.pose
            pos = tr.translation if msgtype == TRANSFORM_STAMPED else tr.position
            o = tr.rotation if msgtype == TRANSFORM_STAMPED else tr.orientation
            rows.append((st, _xyz(pos), (o.x, o.y, o.z, o.w)))
    n = len(rows)
    cols = list(zip(*rows)) if rows else []

    def arr(i: int, k: int) -> np.ndarray:
        return np.asarray(cols[i], np.float64).reshape(n, k) if n else np.zeros((0, k))

    stamps = np.asarray(cols[0] if n else [], np.int64)
    if msgtype == IMU:
        return ImuColumns(topic, frame, stamps, arr(1, 3), arr(2, 3), arr(3, 4), arr(4, 9), (frame,) if n else ())
    if msgtype == ODOMETRY:
        return MotionColumns(topic, msgtype, frame, child, stamps, arr(1, 3), arr(2, 4), arr(3, 36), arr(4, 3),
                             arr(5, 3), arr(6, 36))
    if msgtype == TWIST_STAMPED:
        return MotionColumns(topic, msgtype, frame, child, stamps, _nan(n, 3), _nan(n, 4), None, arr(1, 3),
                             arr(2, 3), None)
    return MotionColumns(topic, msgtype, frame, child, stamps, arr(1, 3), arr(2, 4), None, _nan(n, 3), _nan(n, 3),
                         None)


__all__ = ["ImuColumns", "MotionColumns", "POSE_TYPES", "read_series"]
