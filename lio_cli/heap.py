"""The C heap's free pages handed back to the kernel after each run of a ``lio batch`` worker.

Arrays of varying sizes (on a 16-beam log, blocks of 256-512 kB; the per-scan ones now come from
``buffers.ArrayPool``) leave holes inside glibc's heap that free() keeps resident, since glibc only gives memory
back from the heap's top. ``malloc_trim(0)`` releases every whole free page anywhere in the heap (and the other
arenas) without moving anything, so a worker's next run starts from what is really in use. Not done per scan
(the next scans fault the same pages back in: CPU, and the run's peak stays) nor at the end of a single command
(the process exits; its last steps would fault them back in). glibc only: elsewhere (musl, macOS, Windows) there
is no ``malloc_trim`` and this is a no-op (docs/benchmarks.md, issue 29).
"""

from __future__ import annotations

import ctypes
import sys
from collections.abc import Callable
from functools import cache


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


def trim_heap() -> bool:
    """Hand the C heap's free pages back to the kernel; False where there is no glibc (nothing done)."""
    trim = glibc_trim()
    if trim is None:
        return False
    trim()
    return True


__all__ = ["glibc_trim", "trim_heap"]
