"""A voxel-downsampled point map that grows scan by scan: the first point to reach a voxel stays.

Memory follows the mapped volume (one float32 point and one int64 key per occupied voxel), not the log's length;
the keys are sorted numpy arrays, so a scan costs numpy work, not a Python step per point.
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
        # the occupied voxels' keys, sorted: a large array merged rarely and a small one merged per scan
        self._keys = np.zeros(0, dtype=np.int64)
        self._recent = np.zeros(0, dtype=np.int64)
        self._count = 0
        self._chunks: list[np.ndarray] = []
        self.outside = 0  # points beyond the key range, left out

    def __len__(self) -> int:
        return self._count

    def _occupied(self, keys: np.ndarray) -> np.ndarray:
        """Which of ``keys`` name a voxel already occupied."""
        found = np.zeros(len(keys), dtype=bool)
        for known in (self._keys, self._recent):
            if len(known):
                i = np.minimum(np.searchsorted(known, keys), len(known) - 1)
                found |= known[i] == keys
        return found

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
        fresh = ~self._occupied(uniq)
        if not fresh.any():
            return
        new = uniq[fresh]  # sorted, as np.unique returns them
        self._recent = np.insert(self._recent, np.searchsorted(self._recent, new), new)
        if len(self._recent) > max(1 << 16, len(self._keys) >> 3):  # amortised: each key is merged O(log) times
            self._keys, self._recent = np.sort(np.concatenate([self._keys, self._recent])), self._recent[:0]
        self._count += int(fresh.sum())
        self._chunks.append(pts[first[fresh]].astype(np.float32))

    def points(self) -> np.ndarray:
        """The map's points (M,3) float32, in the order their voxels were first reached."""
        if not self._chunks:
            return np.zeros((0, 3), dtype=np.float32)
        return np.concatenate(self._chunks)
