"""A voxel-downsampled point map that grows scan by scan: the first point to reach a voxel stays.

Memory follows the mapped volume (one float32 point and one key per occupied voxel), not the log's length.
"""

from __future__ import annotations

import numpy as np

_BITS = 21  # per axis: +-2^20 voxels, +-105 km at 0.1 m
_OFFSET = 1 << (_BITS - 1)


def voxel_keys(points: np.ndarray, voxel_m: float) -> tuple[np.ndarray, np.ndarray]:
    """(one int64 per point naming its voxel, whether the voxel is within the key range) for points (N,3)."""
    ijk = np.floor(points / voxel_m).astype(np.int64) + _OFFSET
    inside = ((ijk >= 0) & (ijk < (1 << _BITS))).all(axis=1)
    return (ijk[:, 0] << (2 * _BITS)) | (ijk[:, 1] << _BITS) | ijk[:, 2], inside


class VoxelMap:
    def __init__(self, voxel_m: float) -> None:
        if not voxel_m > 0:
            raise ValueError(f"voxel size must be positive (got {voxel_m})")
        self.voxel_m = float(voxel_m)
        self._seen: set[int] = set()
        self._chunks: list[np.ndarray] = []
        self.outside = 0  # points beyond the key range, left out

    def __len__(self) -> int:
        return len(self._seen)

    def add(self, points: np.ndarray) -> None:
        """Add world points (N,3); those falling in voxels already occupied are dropped."""
        pts = np.asarray(points, dtype=np.float64)
        pts = pts[np.isfinite(pts).all(axis=1)]
        if len(pts) == 0:
            return
        keys, inside = voxel_keys(pts, self.voxel_m)
        self.outside += int(len(pts) - inside.sum())
        keys, pts = keys[inside], pts[inside]
        uniq, first = np.unique(keys, return_index=True)
        seen = self._seen
        fresh = [i for i, k in zip(first.tolist(), uniq.tolist()) if k not in seen]
        if fresh:
            seen.update(keys[fresh].tolist())
            self._chunks.append(pts[fresh].astype(np.float32))

    def points(self) -> np.ndarray:
        """The map's points (M,3) float32, in the order their voxels were first reached."""
        if not self._chunks:
            return np.zeros((0, 3), dtype=np.float32)
        return np.concatenate(self._chunks)
