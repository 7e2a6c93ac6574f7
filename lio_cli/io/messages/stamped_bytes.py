"""The bytes of the fixed-layout stamped messages (Imu, Odometry, TwistStamped) in ROS 1 and little-endian CDR:
the header (stamp, frame ids) split off with ``struct``, the body a numpy structured dtype of known size.
``series`` reads whole topics with them, ``peek`` the first messages of one."""

from __future__ import annotations

import struct

import numpy as np

from .decode import IMU, ODOMETRY, TWIST_STAMPED

_F8 = "<f8"
_IMU_BODY = np.dtype([("q", _F8, 4), ("qcov", _F8, 9), ("w", _F8, 3), ("wcov", _F8, 9), ("a", _F8, 3),
                      ("acov", _F8, 9)])
_ODOM_BODY = np.dtype([("p", _F8, 3), ("q", _F8, 4), ("pcov", _F8, 36), ("lin", _F8, 3), ("ang", _F8, 3),
                       ("tcov", _F8, 36)])
_TWIST_BODY = np.dtype([("lin", _F8, 3), ("ang", _F8, 3)])
BODY_DTYPES = {IMU: _IMU_BODY, ODOMETRY: _ODOM_BODY, TWIST_STAMPED: _TWIST_BODY}
BULK_TYPES = tuple(BODY_DTYPES)

_HEAD_ROS1 = struct.Struct("<4xIII")  # seq, sec, nsec, frame_id length
_HEAD_CDR = struct.Struct("<4xiII")  # encapsulation, sec, nanosec, frame_id length (NUL included)
_U32 = struct.Struct("<I")


def _string_end(buf, pos: int) -> tuple[int, int]:
    (n,) = _U32.unpack_from(buf, pos)
    return pos + 4, pos + 4 + n


def split_header(buf, cdr: bool, child: bool) -> tuple[int, bytes, bytes, int]:
    """(stamp_ns, frame_id bytes, child_frame_id bytes, body offset) of a serialised stamped message."""
    if cdr:
        if buf[1] != 1:
            raise ValueError("not little-endian CDR")
        sec, nsec, n = _HEAD_CDR.unpack_from(buf, 0)
        frame = bytes(buf[16: 16 + n - 1]) if n else b""
        pos = 16 + n
        kid = b""
        if child:
            pos += -(pos - 4) % 4
            a, b = _string_end(buf, pos)
            kid, pos = bytes(buf[a: b - 1]) if b > a else b"", b
        pos += -(pos - 4) % 8
    else:
        sec, nsec, n = _HEAD_ROS1.unpack_from(buf, 0)
        frame = bytes(buf[16: 16 + n])
        pos = 16 + n
        kid = b""
        if child:
            a, pos = _string_end(buf, pos)
            kid = bytes(buf[a:pos])
    return sec * 1_000_000_000 + nsec, frame, kid, pos


def split_standard(buf: memoryview, cdr: bool, child: bool, size: int) -> tuple[int, bytes, bytes, int, bool] | None:
    """``split_header`` of a message whose body is the ``size`` bytes of its type's standard layout, in the
    encoding ``cdr`` or else the other (MCAP may carry ROS 1 encoded messages: the length tells): (stamp, frame,
    child frame, body position, cdr), or None when the message is not that layout."""
    for enc in (cdr, not cdr):
        try:
            stamp, frame, kid, pos = split_header(buf, enc, child)
        except (struct.error, ValueError, IndexError):
            continue
        if pos + size == len(buf):
            return stamp, frame, kid, pos, enc
    return None


__all__ = ["BODY_DTYPES", "BULK_TYPES", "split_header", "split_standard"]
