"""The one trajectory type: poses of a body frame in a world frame at integer-nanosecond stamps."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np


@dataclass
class Trajectory:
    """Poses ``T_world_body`` (N,4,4) at strictly increasing ``stamps_ns`` (N,) int64.

    ``name`` says where it came from (a file, ``LOG:/topic``, ``odom``); ``kind`` how it was read
    (tum, kitti, topic, tf, odom...), empty when it does not matter.
    """

    stamps_ns: np.ndarray
    poses: np.ndarray
    name: str = ""
    kind: str = ""

    def __len__(self) -> int:
        return len(self.stamps_ns)

    @property
    def positions(self) -> np.ndarray:
        return self.poses[:, :3, 3]
