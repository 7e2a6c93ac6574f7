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


class Rows:
    """Rows of one shape and dtype (a pose, a stamp) appended one at a time into blocks of ``block`` rows, not a
    Python object each: a list as far as a growing track uses one (append, len, a row by index: a view, or a
    Python number for scalar rows; iterate; ``del rows[i:]``); ``np.asarray`` and slices give copies."""

    def __init__(self, shape: tuple[int, ...] = (), dtype=np.float64, block: int = 1024) -> None:
        self.shape, self.dtype, self.block = shape, np.dtype(dtype), block
        self._blocks: list[np.ndarray] = []
        self._n = 0

    def append(self, row) -> None:
        k, i = divmod(self._n, self.block)
        if k == len(self._blocks):
            self._blocks.append(np.empty((self.block, *self.shape), self.dtype))
        self._blocks[k][i] = row
        self._n += 1

    def __len__(self) -> int:
        return self._n

    def __getitem__(self, index):
        if isinstance(index, slice):
            return np.asarray(self)[index]
        index = int(index)
        if index < 0:
            index += self._n
        if not 0 <= index < self._n:
            raise IndexError("row index out of range")
        row = self._blocks[index // self.block][index % self.block]
        return row.item() if not self.shape else row

    def __iter__(self):
        for index in range(self._n):
            yield self[index]

    def __delitem__(self, index: slice) -> None:
        if not isinstance(index, slice) or index.stop is not None or index.step is not None:
            raise TypeError("only rows[i:] can be deleted")
        start = index.start or 0
        self._n = min(self._n, start if start >= 0 else max(0, self._n + start))
        del self._blocks[(self._n + self.block - 1) // self.block:]  # the blocks past the last row

    def __array__(self, dtype=None, copy=None) -> np.ndarray:
        out = np.empty((self._n, *self.shape), self.dtype)
        for k, b in enumerate(self._blocks):
            rows = out[k * self.block:(k + 1) * self.block]
            rows[...] = b[:len(rows)]
        return out if dtype is None else out.astype(dtype, copy=False)
