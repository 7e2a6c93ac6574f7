"""Per-scan arrays from a small pool of buffers kept alive, so they never become holes in the C heap.

A long log's scans allocate blocks of 100 kB-1 MB whose sizes change from scan to scan (decoded clouds, bag
chunks, de-skewed points). Freed, they leave holes that the next, differently sized ones only partly fill, and
glibc's heap spreads (docs/benchmarks.md, issue 29). A pool hands out views of buffers whose capacities are powers
of two and takes a buffer back once nothing refers to it any more (its reference count, so a view kept anywhere
keeps its buffer out of reuse: content is never overwritten while seen).
"""

from __future__ import annotations

import math
import sys
import threading

import numpy as np

MIN_POOLED_BYTES = 65_536  # smaller blocks come from glibc's bins, which reuse them exactly
_getrefcount = sys.getrefcount


def _idle_refs() -> int:
    """The reference count ``ArrayPool`` sees for a buffer held by nothing but its pool (a Python version's own)."""
    probe = [np.empty(1)]
    return _getrefcount(probe[0])


_IDLE = _idle_refs()


class ArrayPool:
    """Up to ``keep`` buffers reused for arrays of at least ``MIN_POOLED_BYTES``; smaller ones are plain
    ``np.empty``. A request with every fitting buffer in use gets a new buffer if the pool has room (or in place
    of an idle buffer of another size), else a plain array."""

    def __init__(self, keep: int = 16) -> None:
        self.keep = keep
        self.bufs: list[np.ndarray] = []
        self.allocated = 0  # buffers made (reuse is every other request)
        self._lock = threading.Lock()  # a check and a hand-out are one step for threads sharing the pool

    def empty(self, shape: int | tuple[int, ...], dtype=np.float64) -> np.ndarray:
        """An uninitialised C-ordered array of ``shape`` and ``dtype``, a view of a pooled buffer."""
        dtype = np.dtype(dtype)
        shape = (shape,) if isinstance(shape, int) else tuple(shape)
        nbytes = dtype.itemsize * math.prod(shape)
        if nbytes < MIN_POOLED_BYTES:
            return np.empty(shape, dtype)
        cap = 1 << (nbytes - 1).bit_length()
        with self._lock:
            bufs = self.bufs
            idle = -1
            for i in range(len(bufs)):
                if _getrefcount(bufs[i]) <= _IDLE:
                    if len(bufs[i]) == cap:
                        return bufs[i][:nbytes].view(dtype).reshape(shape)
                    idle = i
            if len(bufs) >= self.keep and idle < 0:
                return np.empty(shape, dtype)  # every buffer in use: a plain array, not kept
            buf = np.empty(cap, np.uint8)
            if len(bufs) < self.keep:
                bufs.append(buf)
            else:
                bufs[idle] = buf  # an idle buffer of another size makes room
            self.allocated += 1
            return buf[:nbytes].view(dtype).reshape(shape)


__all__ = ["ArrayPool", "MIN_POOLED_BYTES"]
