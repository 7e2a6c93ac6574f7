"""A GPS topic (sensor_msgs/NavSatFix) as positions in a local east-north-up frame.

``read_gps_track`` decodes a topic, drops fixes without a valid status (NO_FIX) or with NaN/out-of-range
coordinates and duplicated or backwards header stamps, counts each, and converts the rest to ENU metres
around an origin: the one given, else the first valid fix. The covariance and status of every kept fix stay
beside its position (the fusion filter weighs them; evaluation only needs positions). ``gps_trajectory``
turns a track into a position-only trajectory (identity rotations).
"""

from __future__ import annotations

import numpy as np

from ...errors import InputError
from ...geodesy import EnuFrame
from ...model.gps import GpsTrack
from ...model.records import NavSatFixRecord


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
        bad_coordinates=bad, bad_stamps=bad_stamps, frame_id=valid[0].frame_id.lstrip("/"),
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
