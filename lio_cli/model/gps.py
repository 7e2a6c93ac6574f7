"""A GPS track: the valid fixes of one NavSatFix topic as positions in a local east-north-up frame."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..geodesy import EnuFrame


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
    frame_id: str = ""  # the antenna's frame (the first valid fix's header)

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
