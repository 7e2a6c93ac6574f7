"""The C heap's free pages handed back to the kernel every so many scans, so a long run's RSS stays flat.

Per-scan arrays of varying sizes (decoded clouds, de-skewed points, kiss-icp's vectors) leave holes inside
glibc's heap that later requests do not fill exactly; glibc only gives memory back from the heap's top, so the
free space in the middle stays resident and grows with the log. ``malloc_trim(0)`` releases every whole free
page anywhere in the heap (and the other arenas) without moving anything. glibc only: elsewhere (musl, macOS,
Windows) there is no ``malloc_trim`` and this is a no-op.
"""

from __future__ import annotations

import ctypes
import sys
from collections.abc import Callable
from functools import cache

TRIM_EVERY_SCANS = 100  # about 10 s of a 10 Hz LiDAR: the pages faulted back in afterwards cost little


@cache
def glibc_trim() -> Callable[[], int] | None:
    """glibc's ``malloc_trim(0)`` as a function (returns 1 when memory was released), None without glibc."""
    if not sys.platform.startswith("linux"):
        return None
    try:
        libc = ctypes.CDLL(None)  # the symbols the process already has: its C library
        if not hasattr(libc, "gnu_get_libc_version"):  # musl and other C libraries
            return None
        trim = libc.malloc_trim
    except (OSError, AttributeError):
        return None
    trim.argtypes, trim.restype = [ctypes.c_size_t], ctypes.c_int
    return lambda: trim(0)


class HeapTrim:
    """Counts scans and trims the C heap after every ``every``-th (a no-op without glibc)."""

    def __init__(self, every: int = TRIM_EVERY_SCANS, trim: Callable[[], int] | None = None) -> None:
        self.every = every
        self.trim = trim if trim is not None else glibc_trim()
        self.scans = 0
        self.trims = 0

    def scan_done(self) -> None:
        self.scans += 1
        if self.trim is not None and self.scans % self.every == 0:
            self.trim()
            self.trims += 1


__all__ = ["TRIM_EVERY_SCANS", "HeapTrim", "glibc_trim"]
