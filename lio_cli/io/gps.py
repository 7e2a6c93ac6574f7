"""A GPS topic (sensor_msgs/NavSatFix) as positions in a local east-north-up frame.

``read_gps_track`` decodes a topic, drops fixes without a valid status (NO_FIX) or with NaN/out-of-range
coordinates and duplicated or backwards header stamps, counts each, and converts the rest to ENU metres
around an origin: the one given, else the first valid fix. The covariance and status of every kept fix stay
beside its position (the fusion filter weighs them; evaluation only needs positions). ``gps_trajectory``
turns a track into a position-only trajectory (identity rotations).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..errors import InputError
from ..geodesy import EnuFrame
from .records import NavSatFixRecord


@dataclass
class GpsTrack:
    """Valid fixes of one topic in ENU: ``enu_m[i]`` is the antenna position at ``stamps_ns[i]``."""

    topic: str
    stamps_ns: np.ndarray  # (N,) int64, strictly increasing
    enu_m: np.ndarray  # (N,3)
    covariance_m2: np.ndarray  # (N,3,3) ENU, as the receiver reported it
    covariance_type: np.ndarray  # (N,) int
    status: np.ndarray  # (N,) int: 0 fix, 1 SBAS, 2 GBAS
    origin: EnuFrame
    origin_source: str  # "first valid fix" or "given"
    messages: int  # on the topic
    no_fix: int  # dropped: status NO_FIX
    bad_coordinates: int  # dropped: NaN, infinite or out-of-range latitude/longitude/altitude
    bad_stamps: int  # dropped: duplicated or backwards header stamps

    def __len__(self) -> int:
        return len(self.stamps_ns)

    @property
    def farthest_m(self) -> float:
        """Largest horizontal distance of a fix from the origin (a far origin tilts the ENU axes)."""
        return float(np.max(np.hypot(self.enu_m[:, 0], self.enu_m[:, 1])))

    @property
    def dropped(self) -> int:
        return self.no_fix + self.bad_coordinates + self.bad_stamps

    def summary(self) -> dict:
        return {"topic": self.topic, "messages": self.messages, "used": len(self), "dropped_no_fix": self.no_fix,
                "dropped_bad_coordinates": self.bad_coordinates, "dropped_bad_stamps": self.bad_stamps,
                "origin": self.origin.to_dict(), "origin_source": self.origin_source}

    def describe(self) -> str:
        """One line for people: what was used, what was dropped and why, where the origin is."""
        drops = [f"{n} {what}" for n, what in ((self.no_fix, "without a fix"),
                                                (self.bad_coordinates, "with NaN or out-of-range coordinates"),
                                                (self.bad_stamps, "with repeated or backwards stamps")) if n]
        o = self.origin
        return (f"GPS {self.topic}: {len(self)} of {self.messages} fixes used"
                f"{' (dropped ' + ', '.join(drops) + ')' if drops else ''}; ENU origin {o.lat_deg:.8f}, "
                f"{o.lon_deg:.8f}, {o.alt_m:.3f} m ({self.origin_source})")


def track_from_fixes(topic: str, fixes: list[NavSatFixRecord], origin: EnuFrame | None = None,
                     bad_stamps: int = 0, where: str = "") -> GpsTrack:
    """Keep the valid fixes (in the given order, stamps increasing) and express them in ENU around ``origin``."""
    valid = [f for f in fixes if f.valid]
    no_fix = sum(1 for f in fixes if f.invalid_reason == "no fix")
    bad = len(fixes) - len(valid) - no_fix
    if not valid:
        raise InputError(
            f"{where}{topic}: no valid fix among its {len(fixes) + bad_stamps} NavSatFix messages "
            f"({no_fix} without a fix (status NO_FIX), {bad} with NaN or out-of-range coordinates"
            f"{f', {bad_stamps} with repeated or backwards stamps' if bad_stamps else ''})"
        )
    source = "given"
    if origin is None:
        first = valid[0]
        origin = EnuFrame(first.latitude_deg, first.longitude_deg, first.altitude_m)
        source = "first valid fix"
    lla = np.array([(f.latitude_deg, f.longitude_deg, f.altitude_m) for f in valid])
    return GpsTrack(
        topic=topic,
        stamps_ns=np.array([f.stamp_ns for f in valid], dtype=np.int64),
        enu_m=origin.to_enu(lla[:, 0], lla[:, 1], lla[:, 2]),
        covariance_m2=np.array([f.position_covariance_m2 for f in valid]),
        covariance_type=np.array([f.covariance_type for f in valid], dtype=np.int64),
        status=np.array([f.status for f in valid], dtype=np.int64),
        origin=origin, origin_source=source, messages=len(fixes) + bad_stamps, no_fix=no_fix,
        bad_coordinates=bad, bad_stamps=bad_stamps,
    )


def read_gps_track(log, topic: str, origin: EnuFrame | None = None) -> GpsTrack:
    """The valid fixes of a NavSatFix topic of an open log, in ENU (see the module docstring)."""
    from .stream import SensorStream

    stream = SensorStream(log, {"gps": topic}, strict=False)
    fixes = [rec.data for rec in stream]
    bad_stamps = stream.stats.duplicates.get(topic, 0) + stream.stats.backwards.get(topic, 0)
    return track_from_fixes(topic, fixes, origin, bad_stamps, where=f"{log.path}: topic ")


def gps_poses(track: GpsTrack) -> np.ndarray:
    """Poses (N,4,4) of a track: ENU positions with identity rotations (the orientation is unknown)."""
    poses = np.repeat(np.eye(4)[None], len(track), axis=0)
    poses[:, :3, 3] = track.enu_m
    return poses
