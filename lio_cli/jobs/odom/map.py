"""``lio odom --map``: the run's de-skewed scans at their poses, voxel-downsampled, in the trajectory's world.

Each scan's points wait (float32, base frame) only until the odometry can no longer change its pose (the
start-up window's poses are replaced when the IMU state starts); then they go into a voxel grid in the
odometry's internal world. Memory follows the mapped volume and the start-up window, not the log's length. At
the end the grid's points are levelled into the output world, as the trajectory is, and voxelised once more
there, so the file holds one point per occupied voxel of the written frame.
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np

from ...core.deskew.voxel_map import VoxelMap

ScanSink = Callable[[int, np.ndarray, np.ndarray], None]  # (stamp_ns, T_world_base, points in base) of a settled scan


class RunMap:
    """The map of one run; ``scan`` is the odometry's ``scan_sink``, ``settle`` follows its settled poses.
    ``voxel_m`` None: no grid, only ``on_settled`` told of each settled scan."""

    def __init__(self, voxel_m: float | None, on_settled: ScanSink | None = None) -> None:
        self.voxels = VoxelMap(voxel_m) if voxel_m else None
        self.on_settled = on_settled
        self.pending: dict[int, np.ndarray] = {}  # stamp -> de-skewed points of a scan whose pose may still change
        self.mapped = 0  # poses whose scans are in the grid (or had none)
        self.scans = 0  # scans in the grid

    @property
    def voxel_m(self) -> float:
        return self.voxels.voxel_m

    def scan(self, stamp_ns: int, points: np.ndarray | None) -> None:
        if points is None:
            self.pending.pop(stamp_ns, None)
        else:
            self.pending[stamp_ns] = np.asarray(points, dtype=np.float32)

    def settle(self, stamps_ns: list[int], poses: list[np.ndarray], upto: int) -> None:
        """Put the scans of poses ``mapped..upto`` (final now) into the grid at those poses."""
        if upto <= self.mapped:
            return
        for i in range(self.mapped, upto):
            pts = self.pending.pop(int(stamps_ns[i]), None)
            if pts is not None:
                T = poses[i]
                if self.voxels is not None:
                    self.voxels.add(pts @ T[:3, :3].T.astype(np.float32) + T[:3, 3].astype(np.float32))
                if self.on_settled is not None:
                    self.on_settled(int(stamps_ns[i]), T, pts)
                self.scans += 1
        last = int(stamps_ns[upto - 1])
        for stamp in [s for s in self.pending if s <= last]:  # scans a replay dropped
            del self.pending[stamp]
        self.mapped = upto

    def cloud(self, level: np.ndarray) -> np.ndarray:
        """The map (M,3) float32 in the output world (``level`` @ the internal world), one point per voxel there."""
        pts = self.voxels.points().astype(np.float64)
        out = (pts @ level[:3, :3].T + level[:3, 3]).astype(np.float32)
        grid = VoxelMap(self.voxel_m)
        grid.add(out)
        return grid.points()


__all__ = ["RunMap"]
