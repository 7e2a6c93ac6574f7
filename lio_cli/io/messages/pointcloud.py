"""Decode ``sensor_msgs/PointCloud2`` and ``sensor_msgs/LaserScan`` into :class:`PointCloud`.

Per-point time conventions (DESIGN.md): ``time`` (Velodyne, float s relative), ``t`` (Ouster, uint32 ns
relative), ``offset_time`` (Livox, uint32 ns relative), ``timestamp`` (Hesai, float64 s absolute),
``stamps``/``timestamps``. Float fields are seconds, integer fields nanoseconds; a value too large to be an
offset is absolute time. Relative offsets are added to the header stamp, which may mark the scan's start
(offsets >= 0) or end (offsets <= 0). Without a time field, stamps are derived from azimuth.
"""

from __future__ import annotations

import numpy as np

from ...buffers import ArrayPool
from ...errors import InputError
from ...model.records import PointCloud, TimeConvention

# sensor_msgs/PointField datatypes -> numpy type codes
_DATATYPES = {1: "i1", 2: "u1", 3: "i2", 4: "u2", 5: "i4", 6: "u4", 7: "f4", 8: "f8"}
# Field names searched, in order, for per-point time, with the label used in reports.
_TIME_FIELDS = (
    ("t", "ouster"),
    ("offset_time", "livox"),
    ("time", "velodyne"),
    ("timestamp", "hesai"),
    ("timestamps", "stamps"),
    ("stamps", "stamps"),
)
_ABSOLUTE_S = 1e6  # a float "offset" beyond 11.6 days is absolute time
_ABSOLUTE_NS = 1e15

NAMED_CONVENTIONS = {
    "velodyne": TimeConvention("velodyne", "time", 1e9, False),
    "ouster": TimeConvention("ouster", "t", 1.0, False),
    "livox": TimeConvention("livox", "offset_time", 1.0, False),
    "hesai": TimeConvention("hesai", "timestamp", 1e9, True),
    "azimuth": TimeConvention("azimuth", None, 1.0, False),
    "none": TimeConvention("none", None, 1.0, False),
}
_UNITS = {"s": 1e9, "ms": 1e6, "us": 1e3, "ns": 1.0}

DEFAULT_SCAN_PERIOD_NS = 100_000_000
# A point whose time lies farther than this from the median time of its scan is a bad point (a sweep lasts a
# tenth of a second; 5e5 s in one point is damage), dropped and counted like a NaN return.
MAX_POINT_TIME_SPREAD_NS = 1_000_000_000
SPIN_AGREEMENT = 0.9  # share of azimuth steps turning one way for an unorganised cloud to be a spinning sweep
_POOL = ArrayPool()  # decoded points and stamps: clouds wait for their IMU, then are dropped


def parse_time_convention(spec: str) -> TimeConvention:
    """``velodyne|ouster|livox|hesai|azimuth|none``, ``FIELD:UNIT[:abs|rel]`` (UNIT in s, ms, us, ns; relative
    unless ``abs``) or ``SEC_FIELD+NSEC_FIELD[:abs|rel]`` (whole seconds plus nanoseconds in two integer fields;
    absolute unless ``rel``)."""
    if spec in NAMED_CONVENTIONS:
        return NAMED_CONVENTIONS[spec]
    parts = spec.split(":")
    pair = parts[0].split("+")
    if len(pair) == 2 and all(pair) and len(parts) <= 2 and (len(parts) == 1 or parts[1] in ("abs", "rel")):
        return TimeConvention("split", pair[0], 1e9, len(parts) == 1 or parts[1] == "abs", pair[1])
    if len(parts) in (2, 3) and parts[0] and "+" not in parts[0] and parts[1] in _UNITS \
            and (len(parts) == 2 or parts[2] in ("abs", "rel")):
        return TimeConvention("custom", parts[0], _UNITS[parts[1]], len(parts) == 3 and parts[2] == "abs")
    raise InputError(
        f"unknown per-point time convention '{spec}' (use {', '.join(NAMED_CONVENTIONS)}, FIELD:UNIT[:abs|rel] "
        "or SEC_FIELD+NSEC_FIELD[:abs|rel], e.g. time:s, t:ns or time_sec+time_nsec)"
    )


def stamp_to_ns(stamp) -> int:
    """builtin_interfaces/Time (ROS 1 or 2) to integer ns."""
    return int(stamp.sec) * 1_000_000_000 + int(stamp.nanosec)


def cloud_dtype(msg) -> np.dtype:
    """The numpy structured dtype one point of ``msg`` has, from its fields, point_step and endianness."""
    order = ">" if msg.is_bigendian else "<"
    names, formats, offsets = [], [], []
    for f in msg.fields:
        if not f.name or f.name in names:  # unnamed padding fields, or a repeated name: keep the first
            continue
        code = _DATATYPES.get(int(f.datatype))
        if code is None:
            raise InputError(f"PointCloud2 field '{f.name}' has unknown datatype {f.datatype}")
        names.append(f.name)
        formats.append((order + code, (int(f.count),)) if int(f.count) > 1 else order + code)
        offsets.append(int(f.offset))
    try:
        return np.dtype({"names": names, "formats": formats, "offsets": offsets, "itemsize": int(msg.point_step)})
    except (ValueError, TypeError) as err:
        layout = ", ".join(f"{n}@{o}" for n, o in zip(names, offsets))
        raise InputError(
            f"PointCloud2 fields ({layout}) do not fit its point_step of {msg.point_step} bytes ({err})"
        ) from err


def _structured(msg) -> np.ndarray:
    dtype = cloud_dtype(msg)
    height, width = int(msg.height), int(msg.width)
    data = np.asarray(msg.data, dtype=np.uint8)
    row_bytes = width * int(msg.point_step)
    if height * width == 0:
        return np.zeros(0, dtype=dtype)
    row_step = int(msg.row_step) or row_bytes
    if len(data) < (height - 1) * row_step + row_bytes:
        raise InputError(
            f"PointCloud2 data holds {len(data)} bytes, fewer than {height}x{width} points of {msg.point_step} bytes"
        )
    if row_step != row_bytes:  # rows padded: drop the padding per row
        data = np.lib.stride_tricks.as_strided(data, (height, row_bytes), (row_step, 1)).reshape(-1)
    else:
        data = data[: height * row_bytes]
    return np.frombuffer(np.ascontiguousarray(data).data, dtype=dtype, count=height * width)


def _typical(values: np.ndarray) -> float:
    """The median magnitude of the first values of a time field (one absurd value does not make it absolute)."""
    vals = np.abs(np.asarray(values[:256], dtype=np.float64))
    vals = vals[np.isfinite(vals)]
    return float(np.median(vals)) if len(vals) else 0.0


def _split_time_fields(fields: dict[str, int]) -> tuple[str, str] | None:
    """Integer fields holding seconds and nanoseconds of one time (``time_sec`` + ``time_nsec``, ``sec`` +
    ``nsec``, ``t_sec`` + ``t_nanosec`` ...), or None."""
    for name, dtype in fields.items():
        if not name.endswith("sec") or name.endswith(("nsec", "usec", "msec", "nanosec")) or dtype in (7, 8):
            continue
        stem = name[:-3]
        for ns in (stem + "nsec", stem + "nanosec"):
            if ns in fields and fields[ns] not in (7, 8):
                return name, ns
    return None


def spins(xyz: np.ndarray) -> bool:
    """Are an unorganised cloud's points in the firing order of a spinning sensor (azimuth turning one way)?"""
    if len(xyz) < 3:
        return False
    az = np.arctan2(xyz[:, 1], xyz[:, 0])
    steps = (np.diff(az) + np.pi) % (2 * np.pi) - np.pi
    steps = steps[np.abs(steps) > 1e-4]  # points of one firing (several rings) share an azimuth
    if len(steps) == 0:
        return False
    turning = max(np.count_nonzero(steps > 0), np.count_nonzero(steps < 0)) / len(steps)
    return turning >= SPIN_AGREEMENT


def detect_time_convention(msg) -> TimeConvention:
    """The per-point time convention of a cloud message, from its fields (and the values' typical magnitude).

    Without a time field, an organised cloud's column index or an unorganised cloud's azimuth gives the
    stamps, but only when the points are in a spinning sensor's firing order; otherwise (a raster scanner, a
    cloud sorted another way) every point is at the header stamp, and the convention says so."""
    fields = {f.name: int(f.datatype) for f in msg.fields}
    n = int(msg.width) * int(msg.height)
    for name, label in _TIME_FIELDS:
        if name in fields:
            is_float = fields[name] in (7, 8)
            scale = 1e9 if is_float else 1.0
            absolute = label == "hesai"
            if n > 0:
                col = _structured(msg)[name]
                absolute = _typical(col if col.ndim == 1 else col[:, 0]) > (_ABSOLUTE_S if is_float else _ABSOLUTE_NS)
            return TimeConvention(label, name, scale, absolute)
    pair = _split_time_fields(fields)
    if pair is not None:
        absolute = n == 0 or _typical(_structured(msg)[pair[0]]) > _ABSOLUTE_S
        return TimeConvention("split", pair[0], 1e9, absolute, pair[1])
    if int(msg.height) <= 1 and n > 0 and {"x", "y", "z"} <= set(fields):
        arr = _structured(msg)
        x, y, z = (np.asarray(arr[c], dtype=np.float64) for c in "xyz")
        ok = np.isfinite(x) & np.isfinite(y) & np.isfinite(z) & ((x != 0) | (y != 0) | (z != 0))
        if not spins(np.stack([x[ok], y[ok], z[ok]], axis=1)):
            return NAMED_CONVENTIONS["none"]
    return NAMED_CONVENTIONS["azimuth"]


def _azimuth_offsets_ns(xyz: np.ndarray, period_ns: int, organised_width: int | None) -> np.ndarray:
    """Offsets from scan start for a spinning sensor, from column index or unwrapped azimuth."""
    n = len(xyz)
    if n == 0:
        return np.zeros(0, np.int64)
    if organised_width:
        col = np.arange(n) % organised_width
        return (col * (period_ns / organised_width)).astype(np.int64)
    az = np.arctan2(xyz[:, 1], xyz[:, 0])
    steps = np.diff(az)
    steps = (steps + np.pi) % (2 * np.pi) - np.pi
    direction = -1.0 if np.median(steps) < 0 else 1.0  # clockwise spin (Velodyne) gives decreasing azimuth
    frac = ((direction * (az - az[0])) % (2 * np.pi)) / (2 * np.pi)
    return (frac * period_ns).astype(np.int64)


def decode_pointcloud2(
    msg,
    convention: TimeConvention | None = None,
    scan_period_ns: int = DEFAULT_SCAN_PERIOD_NS,
) -> PointCloud:
    """Points (N,3) in the sensor frame with absolute per-point stamps; NaN/zero returns dropped with them."""
    header_ns = stamp_to_ns(msg.header.stamp)
    names = {f.name for f in msg.fields}
    missing = {"x", "y", "z"} - names
    if missing:
        raise InputError(f"PointCloud2 has no {', '.join(sorted(missing))} field(s); fields are {sorted(names)}")
    for f in msg.fields:
        if f.name in ("x", "y", "z") and int(f.count) != 1:
            raise InputError(f"PointCloud2 field '{f.name}' has count {int(f.count)}; a coordinate must have count 1")
    conv = convention or detect_time_convention(msg)
    absent = [f for f in conv.fields if f not in names]
    if absent:
        raise InputError(
            f"PointCloud2 has no per-point time field '{absent[0]}' (fields: {', '.join(sorted(names))})"
        )
    arr = _structured(msg)
    # validity first, on contiguous 1-D columns (faster than reductions over (N,3)): only valid points converted
    x, y, z = (np.ascontiguousarray(arr[c]) for c in "xyz")
    valid = np.isfinite(x) & np.isfinite(y) & np.isfinite(z) & ((x != 0) | (y != 0) | (z != 0))
    raw_t = raw_ns = None
    if conv.field is not None:
        raw_t = _first_element(arr[conv.field])
        if conv.field_ns is not None:
            raw_ns = _first_element(arr[conv.field_ns])
            if raw_t.dtype.kind == "f" or raw_ns.dtype.kind == "f":
                raise InputError(f"split per-point time fields '{conv.field}' + '{conv.field_ns}' must be integers")
        elif raw_t.dtype.kind == "f":
            valid &= np.isfinite(raw_t)  # a point without a usable time cannot be deskewed
    n_valid = int(np.count_nonzero(valid))
    dropped = len(arr) - n_valid
    keep = slice(None) if dropped == 0 else valid
    xyz = _POOL.empty((n_valid, 3))
    xyz[:, 0], xyz[:, 1], xyz[:, 2] = x[keep], y[keep], z[keep]
    bad_times = 0
    if raw_t is not None:
        stamps = _offsets_ns(raw_t[keep], None if raw_ns is None else raw_ns[keep], conv, header_ns)
        good = _plausible_times(stamps)
        if good is not None:  # absurd times: those points are dropped as bad points (rare: not the fast path)
            bad_times = n_valid - int(np.count_nonzero(good))
            valid[np.flatnonzero(valid)[~good]] = False
            stamps, xyz = stamps[good], xyz[good]
            n_valid -= bad_times
            dropped += bad_times
        if stamps.dtype != np.int64:
            stamps = _cast(stamps, np.int64)
        stamps += header_ns
    if raw_t is None and conv.name == "azimuth":
        if int(msg.height) > 1:  # organised: the column index is the firing order
            width = int(msg.width)
            col = np.flatnonzero(valid) % width if dropped else np.arange(n_valid) % width
            stamps = header_ns + (col * (scan_period_ns / width)).astype(np.int64)
        else:
            stamps = header_ns + _azimuth_offsets_ns(xyz, scan_period_ns, None)
    elif raw_t is None:
        stamps = np.full(n_valid, header_ns, dtype=np.int64)
    marks = _header_marks(header_ns, stamps)
    return PointCloud(header_ns, str(msg.header.frame_id), xyz, stamps, conv, marks, dropped,
                      bad_times=bad_times, kept=valid if dropped else None)


def _cast(values: np.ndarray, dtype) -> np.ndarray:
    """``values.astype(dtype)`` into a pooled array."""
    out = _POOL.empty(values.shape, dtype)
    np.copyto(out, values, casting="unsafe")
    return out


def _first_element(col: np.ndarray) -> np.ndarray:
    """A time field with count > 1: the first element is the point's time."""
    return col[:, 0] if col.ndim > 1 else col


def _offsets_ns(raw_t: np.ndarray, raw_ns: np.ndarray | None, conv: TimeConvention, header_ns: int) -> np.ndarray:
    """Each point's time relative to the header stamp, in ns: float64 (rounded) for float fields, int64 for
    integer ones. Absurd values may overflow to inf here, silently; ``_plausible_times`` drops them."""
    if raw_ns is not None:  # whole seconds + nanoseconds, exact in int64
        t = raw_t.astype(np.int64) * 1_000_000_000 + raw_ns.astype(np.int64)
        return t - header_ns if conv.absolute else t
    if raw_t.dtype.kind == "f":
        with np.errstate(over="ignore", invalid="ignore"):
            # in place: every temporary of this size is a fresh mmap (and page faults) per scan
            t = _cast(raw_t, np.float64)
            if conv.absolute and conv.scale_ns == 1e9:
                # seconds since epoch: the header's whole seconds first (exact), then its fraction: no rounding added
                sec, nsec = divmod(header_ns, 1_000_000_000)
                t -= float(sec)
                t *= 1e9
                t -= float(nsec)
            elif conv.absolute:
                t *= conv.scale_ns
                t -= float(header_ns)
            else:
                t *= conv.scale_ns
            np.rint(t, out=t)
        return t
    t = raw_t.astype(np.int64)
    if conv.scale_ns != 1.0:
        t = np.rint(t * conv.scale_ns).astype(np.int64)
    return t - header_ns if conv.absolute else t


def _plausible_times(rel: np.ndarray) -> np.ndarray | None:
    """None when every point time is finite and within ``MAX_POINT_TIME_SPREAD_NS`` of the others (the usual
    case, checked by min and max alone), else the mask of the times within that of the scan's median."""
    if len(rel) == 0:
        return None
    lo, hi = rel.min(), rel.max()
    if np.isfinite(lo) and np.isfinite(hi) and int(hi) - int(lo) <= MAX_POINT_TIME_SPREAD_NS \
            and abs(int(lo)) < 2**62 and abs(int(hi)) < 2**62:
        return None
    with np.errstate(invalid="ignore", over="ignore"):
        finite = rel[np.isfinite(rel)] if rel.dtype.kind == "f" else rel
        if len(finite) == 0:
            return np.zeros(len(rel), dtype=bool)
        mid = float(np.median(finite))
        rel_f = rel.astype(np.float64)
        # near the median, and small enough that the header stamp plus it still fits in int64
        return (np.abs(rel_f - mid) <= MAX_POINT_TIME_SPREAD_NS) & (np.abs(rel_f) < 2.0**62)


def _header_marks(header_ns: int, stamps: np.ndarray) -> str:
    if len(stamps) == 0:
        return "start"
    lo, hi = int(stamps.min()), int(stamps.max())
    return "end" if abs(hi - header_ns) < abs(header_ns - lo) else "start"


def decode_laserscan(msg) -> PointCloud:
    """Planar points (z = 0) with per-beam stamps from ``time_increment``; invalid ranges dropped."""
    header_ns = stamp_to_ns(msg.header.stamp)
    ranges = np.asarray(msg.ranges, dtype=np.float64)
    angles = float(msg.angle_min) + float(msg.angle_increment) * np.arange(len(ranges))
    stamps = header_ns + np.rint(np.arange(len(ranges)) * float(msg.time_increment) * 1e9).astype(np.int64)
    valid = np.isfinite(ranges) & (ranges >= float(msg.range_min)) & (ranges <= float(msg.range_max))
    r, a = ranges[valid], angles[valid]
    xyz = np.stack([r * np.cos(a), r * np.sin(a), np.zeros_like(r)], axis=1)
    conv = TimeConvention("laserscan", "time_increment", 1e9, False)
    return PointCloud(
        header_ns, str(msg.header.frame_id), xyz, stamps[valid], conv, "start", int((~valid).sum()), planar=True
    )
