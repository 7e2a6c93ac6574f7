"""Write a scan back with new coordinates: a PointCloud2 with its bytes patched, or a LaserScan as a cloud.

A de-skewed PointCloud2 keeps everything of the original but x/y/z of its valid points, its header stamp and
its per-point time field: same fields, point_step, row padding, point order and count; invalid points (NaN
or zero returns, NaN times) keep their bytes. The time field is rewritten relative to the new header stamp
(absolute time fields stay as they are). When the output holds the input's encoding the message bytes are
patched in place (stamp and data), so a ROS 1 header's ``seq`` and every other byte stay; otherwise the
message is built again from its fields by the writer's typestore.
"""

from __future__ import annotations

import struct

import numpy as np

from ...errors import InputError
from ...model.records import TimeConvention
from .pointcloud import cloud_dtype, stamp_to_ns
from .rawmsg import RawPointCloud2

_STAMP = {"ros1": struct.Struct("<II"), "cdr": struct.Struct("<iI")}  # sec, nsec at byte 4 in both encodings


def points_view(data: np.ndarray, msg) -> np.ndarray:
    """A writable (height, width) structured view of ``data`` (a copy of ``msg.data``), rows padded or not."""
    dtype = cloud_dtype(msg)
    h, w = int(msg.height), int(msg.width)
    if h * w == 0:
        return np.zeros((h, w), dtype=dtype)
    row_step = int(msg.row_step) or w * int(msg.point_step)
    if len(data) < (h - 1) * row_step + w * int(msg.point_step):
        raise InputError(f"PointCloud2 data holds {len(data)} bytes, fewer than {h}x{w} points of {msg.point_step} bytes")
    return np.ndarray((h, w), dtype=dtype, buffer=data, offset=0, strides=(row_step, int(msg.point_step)))


def valid_mask(view: np.ndarray, conv: TimeConvention) -> np.ndarray:
    """The points ``decode_pointcloud2`` keeps: finite x/y/z not all zero, and a finite time when it is a float."""
    x, y, z = view["x"], view["y"], view["z"]
    valid = np.isfinite(x) & np.isfinite(y) & np.isfinite(z) & ((x != 0) | (y != 0) | (z != 0))
    if conv.field is not None:
        t = view[conv.field]
        if t.ndim > 2:
            t = t[..., 0]
        if t.dtype.kind == "f":
            valid &= np.isfinite(t)
    return valid


def shift_time_field(view: np.ndarray, conv: TimeConvention, shift_ns: int) -> None:
    """Add ``shift_ns`` (in the field's unit) to a relative per-point time field, in place; absolute ones stay.
    An unsigned field is held at zero (only invalid points, which no reference instant covers, can go below)."""
    if conv.field is None or conv.absolute:
        return
    if conv.field_ns is not None:  # whole seconds + nanoseconds: shift the total, split it again
        sec, nsec = view[conv.field], view[conv.field_ns]
        total = sec.astype(np.int64) * 1_000_000_000 + nsec.astype(np.int64) + int(shift_ns)
        s_new, ns_new = np.divmod(total, 1_000_000_000)
        sec[...] = np.clip(s_new, np.iinfo(sec.dtype).min, np.iinfo(sec.dtype).max)
        nsec[...] = ns_new
        return
    col = view[conv.field]
    if col.dtype.kind == "f":
        col[...] = col.astype(np.float64) + shift_ns / conv.scale_ns
        return
    info = np.iinfo(col.dtype)
    new = col.astype(np.int64) + int(np.rint(shift_ns / conv.scale_ns))
    col[...] = np.clip(new, info.min, info.max)


def deskewed_data(msg, conv: TimeConvention, xyz_valid: np.ndarray, t_ref_ns: int,
                  kept: np.ndarray | None = None) -> np.ndarray:
    """A copy of ``msg.data`` with the valid points' x/y/z replaced by ``xyz_valid`` (in point order) and the
    time field rewritten relative to ``t_ref_ns``. ``kept``: the points decoding kept (``PointCloud.kept``,
    which also leaves out points with absurd times), else the NaN/zero-return rule of ``valid_mask``."""
    data = np.array(msg.data, dtype=np.uint8, copy=True)
    view = points_view(data, msg)
    valid = valid_mask(view, conv) if kept is None else np.asarray(kept, dtype=bool).reshape(view.shape)
    if int(valid.sum()) != len(xyz_valid):
        raise InputError(f"PointCloud2 has {int(valid.sum())} valid points but {len(xyz_valid)} were de-skewed")
    for k, c in enumerate("xyz"):
        col = view[c]
        col[valid] = xyz_valid[:, k]
    shift_time_field(view, conv, stamp_to_ns(msg.header.stamp) - t_ref_ns)
    return data


def patch_pointcloud2(buf, msg: RawPointCloud2, data: np.ndarray, stamp_ns: int, encoding: str) -> bytes | None:
    """The serialised message ``buf`` (which ``msg`` was parsed from) with its header stamp and point data
    replaced; None when ``msg.data`` is not a view into ``buf``."""
    raw = np.frombuffer(buf, dtype=np.uint8)
    offset = msg.data.__array_interface__["data"][0] - raw.__array_interface__["data"][0]
    if not (0 <= offset and offset + len(msg.data) <= len(raw)) or len(data) != len(msg.data):
        return None
    out = bytearray(buf)
    _STAMP[encoding].pack_into(out, 4, stamp_ns // 1_000_000_000, stamp_ns % 1_000_000_000)
    out[offset:offset + len(data)] = memoryview(np.ascontiguousarray(data))
    return bytes(out)


def build_pointcloud2(make, msg, data: np.ndarray, stamp_ns: int):
    """A PointCloud2 of the writer's typestore (``make``: its MessageFactory) with ``msg``'s layout and new data."""
    PointField = make.T["sensor_msgs/msg/PointField"]
    fields = [PointField(name=f.name, offset=int(f.offset), datatype=int(f.datatype), count=int(f.count))
              for f in msg.fields]
    return make.T["sensor_msgs/msg/PointCloud2"](
        header=make.header(stamp_ns, str(msg.header.frame_id)), height=int(msg.height), width=int(msg.width),
        fields=fields, is_bigendian=bool(msg.is_bigendian), point_step=int(msg.point_step),
        row_step=int(msg.row_step), data=np.asarray(data, dtype=np.uint8), is_dense=bool(msg.is_dense))


def laserscan_valid(msg) -> np.ndarray:
    """The beams ``decode_laserscan`` keeps: finite ranges within [range_min, range_max]."""
    ranges = np.asarray(msg.ranges, dtype=np.float64)
    return np.isfinite(ranges) & (ranges >= float(msg.range_min)) & (ranges <= float(msg.range_max))


def laserscan_cloud(msg, xyz_valid: np.ndarray, t_ref_ns: int) -> np.ndarray:
    """One point per beam (float32 x, y, z, intensity when the scan has one per beam, time in s relative to
    ``t_ref_ns``): ``xyz_valid`` at the valid beams, NaN at the others, beams in scan order."""
    ranges = np.asarray(msg.ranges)
    n = len(ranges)
    intensities = np.asarray(msg.intensities)
    fields = [("x", "<f4"), ("y", "<f4"), ("z", "<f4")]
    if len(intensities) == n and n:
        fields.append(("intensity", "<f4"))
    fields.append(("time", "<f4"))
    arr = np.zeros(n, dtype=np.dtype(fields))
    valid = laserscan_valid(msg)
    for k, c in enumerate("xyz"):
        col = np.full(n, np.nan, dtype=np.float32)
        col[valid] = xyz_valid[:, k]
        arr[c] = col
    if "intensity" in arr.dtype.names:
        arr["intensity"] = intensities
    beam_ns = stamp_to_ns(msg.header.stamp) + np.rint(np.arange(n) * float(msg.time_increment) * 1e9).astype(np.int64)
    arr["time"] = (beam_ns - t_ref_ns) * 1e-9
    return arr
