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
import weakref

import numpy as np

MIN_POOLED_BYTES = 65_536  # smaller arrays stay plain: not the blocks that spread the heap
_getrefcount = sys.getrefcount


def _idle_refs() -> int:
    """The reference count ``ArrayPool`` sees for a buffer held by nothing but its pool (a Python version's own)."""
    probe = [np.empty(1)]
    return _getrefcount(probe[0])


_IDLE = _idle_refs()
_POOLS: weakref.WeakSet = weakref.WeakSet()  # every pool, so a batch worker can empty them between runs


class ArrayPool:
    """Up to ``keep`` buffers reused for arrays of at least ``MIN_POOLED_BYTES``; smaller ones are plain
    ``np.empty``. A request takes the smallest idle buffer of its power-of-two capacity or up to two sizes larger
    (so sizes wobbling across a power of two do not swap buffers); else a new buffer in place of an idle one too
    small, else a new one while the pool has room, else a plain array."""

    def __init__(self, keep: int = 8) -> None:
        self.keep = keep
        self.bufs: list[np.ndarray] = []
        self.allocated = 0  # buffers made (reuse is every other request)
        self._lock = threading.Lock()  # a check and a hand-out are one step for threads sharing the pool
        _POOLS.add(self)

    def empty(self, shape: int | tuple[int, ...], dtype=np.float64) -> np.ndarray:
        """An uninitialised C-ordered array of ``shape`` and ``dtype``, a view of a pooled buffer."""
        dtype = np.dtype(dtype)
        shape = (shape,) if isinstance(shape, int) else tuple(shape)
        nbytes = int(dtype.itemsize * math.prod(shape))
        if nbytes < MIN_POOLED_BYTES:
            return np.empty(shape, dtype)
        cap = 1 << (nbytes - 1).bit_length()
        with self._lock:
            bufs = self.bufs
            best = small = large = -1
            for i in range(len(bufs)):
                if _getrefcount(bufs[i]) <= _IDLE:
                    size = len(bufs[i])
                    if size < cap:
                        small = i
                    elif size <= 4 * cap:
                        if best < 0 or size < len(bufs[best]):
                            best = i
                    elif large < 0 or size > len(bufs[large]):
                        large = i
            if best >= 0:
                buf = bufs[best]
            elif small >= 0 or (large >= 0 and len(bufs) >= self.keep):
                # a full pool gives up its largest idle buffer rather than serve plain arrays beside it for good
                buf = bufs[small if small >= 0 else large] = np.empty(cap, np.uint8)
                self.allocated += 1
            elif len(bufs) < self.keep:
                buf = np.empty(cap, np.uint8)
                bufs.append(buf)
                self.allocated += 1
            else:
                return np.empty(shape, dtype)  # every buffer in use: a plain array
            return buf[:nbytes].view(dtype).reshape(shape)

    def release_idle(self) -> None:
        """Drop the buffers nothing refers to (a worker between runs: the next log's sizes may differ)."""
        with self._lock:
            bufs = self.bufs
            self.bufs = [bufs[i] for i in range(len(bufs)) if _getrefcount(bufs[i]) > _IDLE]  # as ``empty`` counts


def release_idle_buffers() -> None:
    """``ArrayPool.release_idle`` of every pool."""
    for pool in list(_POOLS):
        pool.release_idle()


__all__ = ["ArrayPool", "MIN_POOLED_BYTES", "release_idle_buffers"]
