"""One batch per output root at a time: ``OUT/.lio-batch.lock``, an ``fcntl.flock`` held for the whole batch.

A second batch on the same root is refused at once (exit 2, naming the pid that holds it): two batches would
each take the other's partial folders for a killed batch's leftovers and remove them. The kernel releases the
lock when its process dies, so the lock file of a killed batch is simply taken over.
"""

from __future__ import annotations

import os
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path

from ..errors import InputError

LOCK_FILE = ".lio-batch.lock"


@contextmanager
def batch_lock(root: Path) -> Iterator[Path]:
    """Hold the root's lock for the body; removed on the way out. ``InputError`` when another process holds it."""
    import fcntl

    path = root / LOCK_FILE
    while True:
        try:
            fd = os.open(path, os.O_RDWR | os.O_CREAT, 0o644)
        except OSError as err:
            raise InputError(f"{root}: cannot create the batch's lock file ({err.strerror or err})") from err
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except OSError:
            pid = _holder(fd)
            os.close(fd)
            who = f"pid {pid}" if pid else "another process"
            raise InputError(f"{root}: is in use by {who} (another lio batch writing there); wait for it to end, "
                             "or choose another output root") from None
        try:  # the file may have been removed by its last holder between our open and our lock: take a fresh one
            same = os.fstat(fd).st_ino == os.stat(path).st_ino
        except OSError:
            same = False
        if same:
            break
        os.close(fd)
    try:
        os.ftruncate(fd, 0)
        os.write(fd, f"{os.getpid()}\n".encode())
        yield path
    finally:
        try:
            os.unlink(path)  # while still held: a process that opened it now finds it gone and starts over
        except OSError:
            pass
        os.close(fd)


def _holder(fd: int) -> int | None:
    try:
        return int(os.pread(fd, 32, 0).decode().strip() or 0) or None
    except (OSError, ValueError):
        return None


__all__ = ["LOCK_FILE", "batch_lock"]
