"""Parse the hot message types, sensor_msgs/PointCloud2, sensor_msgs/Imu and nav_msgs/Odometry (wheel
odometry), and tf2_msgs/TFMessage (every run reads /tf_static), straight from their bytes.

A LiDAR log is mostly these; going through a generic typestore deserialiser costs more than the
numpy work on the points. The parsers read ROS 1 serialisation and little-endian CDR (ROS 2, MCAP) and
return light objects with the attributes the decoders use (``header.stamp.sec``, ``fields``, ``data``...).
They return ``None`` for anything they do not handle (big-endian CDR), so the caller falls back to the
typestore; malformed bytes raise ``ValueError``/``struct.error``, which the log reader reports as a
corrupted log.
"""

from __future__ import annotations

import struct
from typing import NamedTuple

import numpy as np

from .decode import ODOMETRY, TF_MESSAGE
from .stamped_bytes import BODY_DTYPES, split_header

_U32 = struct.Struct("<I")
_STAMP_ROS1 = struct.Struct("<III")  # seq, sec, nsec
_STAMP_CDR = struct.Struct("<iI")  # sec, nanosec
_FIELD_ROS1 = struct.Struct("<IBI")  # offset, datatype, count
_LAYOUT = struct.Struct("<BII")  # is_bigendian (ROS 1 only: packed), point_step, row_step
_SIX_F8 = struct.Struct("<3d")


class Time(NamedTuple):
    sec: int
    nanosec: int


class Header(NamedTuple):
    stamp: Time
    frame_id: str


class PointField(NamedTuple):
    name: str
    offset: int
    datatype: int
    count: int


class RawPointCloud2(NamedTuple):
    """The PointCloud2 attributes lio reads; ``data`` is a read-only uint8 view of the message bytes."""

    header: Header
    height: int
    width: int
    fields: list
    is_bigendian: bool
    point_step: int
    row_step: int
    data: np.ndarray
    is_dense: bool


class Vector3(NamedTuple):
    x: float
    y: float
    z: float


class Quaternion(NamedTuple):
    x: float
    y: float
    z: float
    w: float


class Pose(NamedTuple):
    position: Vector3
    orientation: Quaternion


class Twist(NamedTuple):
    linear: Vector3
    angular: Vector3


class PoseWithCovariance(NamedTuple):
    pose: Pose  # the covariance is not read by lio


class TwistWithCovariance(NamedTuple):
    twist: Twist  # the covariance is not read by lio


class RawOdometry(NamedTuple):
    """The nav_msgs/Odometry attributes lio reads (``header``, ``child_frame_id``, ``pose.pose``,
    ``twist.twist``), as the typestore's message has them; not the covariances."""

    header: Header
    child_frame_id: str
    pose: PoseWithCovariance
    twist: TwistWithCovariance


class RawImu(NamedTuple):
    """stamp and frame of a sensor_msgs/Imu with its rates (rad/s) and specific force (m/s^2)."""

    stamp_ns: int
    frame_id: str
    gyro_radps: tuple
    accel_mps2: tuple


def _string(buf, pos: int, cdr: bool) -> tuple[str, int]:
    (n,) = _U32.unpack_from(buf, pos)
    pos += 4
    end = pos + n
    if end > len(buf):
        raise ValueError(f"string of {n} bytes runs past the message end ({len(buf)} bytes)")
    text = bytes(buf[pos : end - 1 if cdr and n else end]).decode()
    return text, end


def _align(pos: int, n: int) -> int:
    """CDR alignment, counted from the end of the 4-byte encapsulation header."""
    return pos + (-(pos - 4) % n)


def _header(buf, cdr: bool) -> tuple[Header, int]:
    if cdr:
        if len(buf) < 4 or buf[1] != 1:  # encapsulation: CDR little-endian only
            return None, 0  # type: ignore[return-value]
        sec, nsec = _STAMP_CDR.unpack_from(buf, 4)
        frame, pos = _string(buf, 12, True)
    else:
        _, sec, nsec = _STAMP_ROS1.unpack_from(buf, 0)
        frame, pos = _string(buf, 12, False)
    return Header(Time(sec, nsec), frame), pos


def parse_pointcloud2(buf, cdr: bool) -> RawPointCloud2 | None:
    header, pos = _header(buf, cdr)
    if header is None:
        return None
    if cdr:
        pos = _align(pos, 4)
    height, width, nfields = struct.unpack_from("<III", buf, pos)
    pos += 12
    if nfields > 4096:
        raise ValueError(f"PointCloud2 claims {nfields} fields")
    fields = []
    for _ in range(nfields):
        if cdr:
            pos = _align(pos, 4)
        name, pos = _string(buf, pos, cdr)
        if cdr:
            pos = _align(pos, 4)
            (offset,) = _U32.unpack_from(buf, pos)
            datatype = buf[pos + 4]
            pos = _align(pos + 5, 4)
            (count,) = _U32.unpack_from(buf, pos)
            pos += 4
        else:
            offset, datatype, count = _FIELD_ROS1.unpack_from(buf, pos)
            pos += 9
        fields.append(PointField(name, offset, datatype, count))
    if cdr:
        is_be = buf[pos]
        pos = _align(pos + 1, 4)
        point_step, row_step, ndata = struct.unpack_from("<III", buf, pos)
        pos += 12
    else:
        is_be, point_step, row_step = _LAYOUT.unpack_from(buf, pos)
        pos += 9
        (ndata,) = _U32.unpack_from(buf, pos)
        pos += 4
    if pos + ndata > len(buf):
        raise ValueError(f"PointCloud2 data of {ndata} bytes runs past the message end ({len(buf)} bytes)")
    data = np.frombuffer(buf, dtype=np.uint8, count=ndata, offset=pos)
    is_dense = bool(buf[pos + ndata]) if pos + ndata < len(buf) else False
    return RawPointCloud2(header, height, width, fields, bool(is_be), point_step, row_step, data, is_dense)


_IMU_HEAD_ROS1 = struct.Struct("<IIII")  # seq, sec, nsec, frame_id length
_IMU_HEAD_CDR = struct.Struct("<4xiII")  # encapsulation, sec, nanosec, frame_id length (with its NUL)


def parse_imu(buf, cdr: bool) -> RawImu | None:
    # hot path (one call per IMU sample): the header is unpacked in one go rather than via _header
    if cdr:
        if len(buf) < 16 or buf[1] != 1:
            return None
        sec, nsec, n = _IMU_HEAD_CDR.unpack_from(buf, 0)
        frame = bytes(buf[16 : 16 + n - 1]).decode() if n else ""
        pos = 16 + n
        pos += -(pos - 4) % 8
    else:
        _, sec, nsec, n = _IMU_HEAD_ROS1.unpack_from(buf, 0)
        frame = bytes(buf[16 : 16 + n]).decode()
        pos = 16 + n
    # orientation (4 f8) and its covariance (9 f8) precede the rates; each vector is followed by 9 f8
    if pos + 296 > len(buf):
        raise ValueError(f"Imu message of {len(buf)} bytes is shorter than its layout")
    return RawImu(sec * 1_000_000_000 + nsec, frame, _SIX_F8.unpack_from(buf, pos + 104),
                  _SIX_F8.unpack_from(buf, pos + 200))


# position, orientation, the pose covariance (36 f8, skipped), linear and angular velocity, twist covariance
_ODOM_BODY = struct.Struct("<7d288x6d288x")
assert _ODOM_BODY.size == BODY_DTYPES[ODOMETRY].itemsize  # the layout series and peek read in bulk


def parse_odometry(buf, cdr: bool) -> RawOdometry | None:
    if cdr and (len(buf) < 4 or buf[1] != 1):
        return None  # big-endian CDR: the typestore
    stamp_ns, frame, kid, pos = split_header(buf, cdr, True)
    if pos + _ODOM_BODY.size > len(buf):
        raise ValueError(f"Odometry message of {len(buf)} bytes is shorter than its layout")
    if pos + _ODOM_BODY.size < len(buf):
        return None  # more than the standard body (an MCAP channel stores no hash to tell): the typestore
    px, py, pz, qx, qy, qz, qw, lx, ly, lz, ax, ay, az = _ODOM_BODY.unpack_from(buf, pos)
    sec, nsec = divmod(stamp_ns, 1_000_000_000)
    return RawOdometry(Header(Time(sec, nsec), frame.decode()), kid.decode(),
                       PoseWithCovariance(Pose(Vector3(px, py, pz), Quaternion(qx, qy, qz, qw))),
                       TwistWithCovariance(Twist(Vector3(lx, ly, lz), Vector3(ax, ay, az))))


class Transform(NamedTuple):
    translation: Vector3
    rotation: Quaternion


class TransformStamped(NamedTuple):
    header: Header
    child_frame_id: str
    transform: Transform


class RawTFMessage(NamedTuple):
    """A tf2_msgs/TFMessage as the typestore's message has it: ``transforms``, each a TransformStamped."""

    transforms: list


_SEVEN_F8 = struct.Struct("<7d")
_MAX_TRANSFORMS = 100_000  # a count beyond this is damage, not a tree


def parse_tf(buf, cdr: bool) -> RawTFMessage | None:
    """A TFMessage; None for big-endian CDR, bytes left over (a definition other than the standard one: an MCAP
    channel stores no hash to tell) or bytes it cannot read (the typestore then reports them in its own words)."""
    if cdr and (len(buf) < 8 or buf[1] != 1):
        return None
    try:
        return _tf_message(buf, cdr)
    except (struct.error, ValueError):
        return None


def _tf_message(buf, cdr: bool) -> RawTFMessage | None:
    pos = 4 if cdr else 0
    (n,) = _U32.unpack_from(buf, pos)
    pos += 4
    if n > _MAX_TRANSFORMS:
        raise ValueError(f"TFMessage claims {n} transforms")
    transforms = []
    for _ in range(n):
        if cdr:
            pos = _align(pos, 4)
            sec, nsec = _STAMP_CDR.unpack_from(buf, pos)
            frame, pos = _string(buf, pos + 8, True)
            child, pos = _string(buf, _align(pos, 4), True)
            pos = _align(pos, 8)
        else:
            _, sec, nsec = _STAMP_ROS1.unpack_from(buf, pos)
            frame, pos = _string(buf, pos + 12, False)
            child, pos = _string(buf, pos, False)
        tx, ty, tz, qx, qy, qz, qw = _SEVEN_F8.unpack_from(buf, pos)
        pos += _SEVEN_F8.size
        transforms.append(TransformStamped(Header(Time(sec, nsec), frame), child,
                                           Transform(Vector3(tx, ty, tz), Quaternion(qx, qy, qz, qw))))
    return RawTFMessage(transforms) if pos == len(buf) else None


RAW_PARSERS = {
    "sensor_msgs/msg/PointCloud2": parse_pointcloud2,
    "sensor_msgs/msg/Imu": parse_imu,
    "nav_msgs/msg/Odometry": parse_odometry,
    TF_MESSAGE: parse_tf,
}
