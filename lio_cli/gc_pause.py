"""Python's cyclic garbage collector paused over a stretch of allocation-heavy work.

The collector runs every few hundred container allocations and walks the young objects, then every so often
all long-lived ones. Reading a log (index entries, per-message values) and a filter's per-sample Python
lists allocate millions of containers that form no reference cycles, so those passes find nothing and cost
time. Reference counting still frees everything as usual; only cycles wait until the collector is back on
(then they are collected).
"""

from __future__ import annotations

import gc
from collections.abc import Iterator
from contextlib import contextmanager


@contextmanager
def cyclic_gc_paused() -> Iterator[None]:
    """Pause the cyclic collector inside the block; back on after it when it was on before (nested or
    concurrent uses never leave it off)."""
    was_on = gc.isenabled()
    gc.disable()
    try:
        yield
    finally:
        if was_on:
            gc.enable()


def freeze_start_up() -> None:
    """Move every object alive now (modules, classes, functions, schemas: a command's start-up) into the
    collector's permanent generation, where its passes no longer walk them, and switch it on.

    For a process that runs one command and exits (``cli.app.entry``, which switches the collector off while
    importing: start-up allocates a few hundred thousand such objects and no garbage). Called again at exit,
    the interpreter's last full pass skips what the run left; objects that die at exit are still freed by
    reference counting."""
    gc.freeze()
    gc.enable()


__all__ = ["cyclic_gc_paused", "freeze_start_up"]
