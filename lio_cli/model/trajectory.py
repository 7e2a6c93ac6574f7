"""The one trajectory type: poses of a body frame in a world frame at integer-nanosecond stamps."""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np

if TYPE_CHECKING:
    from .gps import GpsTrack


@dataclass
class Trajectory:
    """Poses ``T_world_body`` (N,4,4) at strictly increasing ``stamps_ns`` (N,) int64.

    ``name`` says where it came from (a file, ``LOG:/topic``, ``odom``); ``kind`` how it was read
    (tum, kitti, topic, tf, gps, odom...), empty when it does not matter. A GPS trajectory knows positions
    only (its rotations are identity placeholders) and keeps its fixes in ``gps``.
    """

    stamps_ns: np.ndarray
    poses: np.ndarray
    name: str = ""
    kind: str = ""
    gps: GpsTrack | None = None

    @property
    def position_only(self) -> bool:
        return self.kind == "gps"

    def __len__(self) -> int:
        return len(self.stamps_ns)

    @property
    def positions(self) -> np.ndarray:
        return self.poses[:, :3, 3]
