"""Typed sensor records decoded from log messages (DESIGN.md: int64 ns, float64 arrays)."""

from __future__ import annotations

from dataclasses import dataclass, field
from functools import cached_property

import numpy as np


# an IMU sample beyond these is damage, not motion (IMUs saturate near 16-200 g, 35-70 rad/s): dropped, counted
MAX_IMU_ACCEL_MPS2 = 1e4
MAX_IMU_GYRO_RADPS = 1e3
# Likewise an odometry twist beyond these is damage: no wheel, car or drone moves at 1 km/s.
MAX_TWIST_MPS = 1e3
MAX_TWIST_RADPS = 1e3


def on_lidar_clock(imu_stamps_ns: np.ndarray, imu_time_offset_ns: int) -> np.ndarray:
    """IMU stamps moved onto the LiDAR's clock: the offset is added (``imu_time_offset_s``'s convention)."""
    return imu_stamps_ns + np.int64(imu_time_offset_ns)


@dataclass(frozen=True)
class TimeConvention:
    """How a cloud carries per-point time.

    ``field``: the PointCloud2 field name (``None`` when there is none and stamps come from azimuth).
    ``scale_ns``: nanoseconds per unit of the field (1e9 for seconds, 1 for ns).
    ``absolute``: the field holds absolute time instead of an offset from the header stamp.
    ``name``: a short label (velodyne, ouster, livox, hesai, stamps, split, azimuth, none, custom).
    ``field_ns``: time split over two integer fields (Luminar's ``time_sec`` + ``time_nsec``): ``field`` holds the
    whole seconds and ``field_ns`` the nanoseconds.
    """

    name: str
    field: str | None
    scale_ns: float
    absolute: bool = False
    field_ns: str | None = None

    @property
    def fields(self) -> tuple[str, ...]:
        """The PointCloud2 fields this convention reads (none, one, or the seconds and nanoseconds pair)."""
        return tuple(f for f in (self.field, self.field_ns) if f is not None)

    def describe(self) -> str:
        if self.field is None:
            return "none (stamps derived from azimuth)" if self.name == "azimuth" else "none (all points at header stamp)"
        if self.field_ns is not None:
            kind = "absolute" if self.absolute else "relative to header"
            return f"{self.name}: fields '{self.field}' (s) + '{self.field_ns}' (ns), {kind}"
        unit = {1e9: "s", 1e6: "ms", 1e3: "us", 1.0: "ns"}.get(self.scale_ns, f"x{self.scale_ns:g} ns")
        kind = "absolute" if self.absolute else "relative to header"
        return f"{self.name}: field '{self.field}' in {unit}, {kind}"


@dataclass
class PointCloud:
    """One LiDAR scan: points in the sensor frame and each point's capture time.

    ``stamp_ns`` is the header stamp; ``point_stamps_ns`` are absolute, aligned with ``points``.
    ``header_marks`` says whether the header stamp marks the scan's ``start`` or ``end``.
    """

    stamp_ns: int
    frame_id: str
    points: np.ndarray  # (N,3) float64
    point_stamps_ns: np.ndarray  # (N,) int64
    convention: TimeConvention
    header_marks: str = "start"
    dropped: int = 0  # invalid returns dropped while decoding (bad_times included)
    planar: bool = False  # from a LaserScan
    bad_times: int = 0  # of ``dropped``: points whose time lies absurdly far from the scan's other points
    kept: np.ndarray | None = None  # which of the message's points were kept (row order), when some were dropped

    # computed once: the loop asks a scan's span a dozen times (a min/max over every point's stamp each)
    @cached_property
    def start_ns(self) -> int:
        return int(self.point_stamps_ns.min()) if len(self.point_stamps_ns) else self.stamp_ns

    @cached_property
    def end_ns(self) -> int:
        return int(self.point_stamps_ns.max()) if len(self.point_stamps_ns) else self.stamp_ns


@dataclass
class ImuBatch:
    """Consecutive IMU samples as arrays, in the IMU frame."""

    frame_id: str
    stamps_ns: np.ndarray  # (N,) int64
    gyro_radps: np.ndarray  # (N,3)
    accel_mps2: np.ndarray  # (N,3)

    def __len__(self) -> int:
        return len(self.stamps_ns)

    def shifted(self, offset_ns: int) -> "ImuBatch":
        """The same samples re-stamped by :func:`on_lidar_clock`."""
        return ImuBatch(self.frame_id, on_lidar_clock(self.stamps_ns, offset_ns), self.gyro_radps, self.accel_mps2)

    @staticmethod
    def concat(batches: list["ImuBatch"]) -> "ImuBatch":
        if not batches:
            return ImuBatch("", np.zeros(0, np.int64), np.zeros((0, 3)), np.zeros((0, 3)))
        return ImuBatch(
            batches[0].frame_id,
            np.concatenate([b.stamps_ns for b in batches]),
            np.concatenate([b.gyro_radps for b in batches]),
            np.concatenate([b.accel_mps2 for b in batches]),
        )


@dataclass
class OdometryRecord:
    """Wheel/robot odometry: pose of ``child_frame`` in ``frame_id`` and twist in the child frame."""

    stamp_ns: int
    frame_id: str
    child_frame_id: str
    pose: np.ndarray | None  # (4,4), None for a bare TwistStamped
    linear_mps: np.ndarray  # (3,)
    angular_radps: np.ndarray  # (3,)


@dataclass
class PoseRecord:
    """A stamped pose (ground truth): ``T_frame_child``."""

    stamp_ns: int
    frame_id: str
    child_frame_id: str
    pose: np.ndarray  # (4,4)


# sensor_msgs/NavSatStatus values
NAVSAT_STATUS_NO_FIX = -1
NAVSAT_STATUS_FIX = 0
NAVSAT_STATUS_SBAS_FIX = 1
NAVSAT_STATUS_GBAS_FIX = 2
NAVSAT_COVARIANCE_TYPES = ("unknown", "approximated", "diagonal_known", "known")


@dataclass
class NavSatFixRecord:
    """One sensor_msgs/NavSatFix: the WGS84 position of the antenna frame ``frame_id``, as the receiver said.

    ``status``: -1 no fix, 0 fix, 1 SBAS-augmented, 2 ground-based augmentation (e.g. RTK); ``service``: the
    constellations used (bit mask: 1 GPS, 2 GLONASS, 4 COMPASS, 8 GALILEO). ``altitude_m`` is above the WGS84
    ellipsoid. ``position_covariance_m2`` is (3,3) in the local east-north-up frame at the fix;
    ``covariance_type`` indexes ``NAVSAT_COVARIANCE_TYPES`` (0 unknown ... 3 known). Nothing is checked when
    decoding: ``invalid_reason`` says why a fix is unusable.
    """

    stamp_ns: int
    frame_id: str
    status: int
    service: int
    latitude_deg: float
    longitude_deg: float
    altitude_m: float
    position_covariance_m2: np.ndarray  # (3,3)
    covariance_type: int

    @property
    def invalid_reason(self) -> str | None:
        """None for a usable fix; else ``no fix`` or what is wrong with its coordinates."""
        from ..geodesy import check_geodetic

        if self.status < NAVSAT_STATUS_FIX:
            return "no fix"
        return check_geodetic(self.latitude_deg, self.longitude_deg, self.altitude_m)

    @property
    def valid(self) -> bool:
        return self.invalid_reason is None


@dataclass
class TransformRecord:
    """One transform of a TF message: ``T_parent_child``."""

    stamp_ns: int
    parent: str
    child: str
    pose: np.ndarray


@dataclass
class TopicInfo:
    """What a log says about one topic."""

    name: str
    msgtype: str
    count: int
    first_ns: int | None = None
    last_ns: int | None = None

    @property
    def rate_hz(self) -> float | None:
        if self.count < 2 or self.first_ns is None or self.last_ns is None or self.last_ns <= self.first_ns:
            return None
        return (self.count - 1) / ((self.last_ns - self.first_ns) * 1e-9)


@dataclass
class Record:
    """One item of a merged sensor stream: ``kind`` is lidar, imu, wheel, gt or gps."""

    kind: str
    topic: str
    stamp_ns: int
    data: object = field(repr=False)
