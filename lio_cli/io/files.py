"""Atomic outputs: write to a temporary sibling, then rename; never clobber without ``force``."""

from __future__ import annotations

import os
import shutil
import tempfile
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path

from ..errors import InputError


def check_writable(path: Path, force: bool) -> None:
    """Refuse to overwrite an existing output unless ``force``; the parent folder must exist."""
    if path.exists() and not force:
        raise InputError(f"{path}: already exists; pass --force to overwrite it")
    if not path.parent.exists():
        raise InputError(f"{path.parent}: output folder does not exist")


def temp_sibling(path: Path) -> Path:
    """A fresh unused path beside ``path`` (same filesystem, so the final rename is atomic)."""
    fd, name = tempfile.mkstemp(prefix=f".{path.name}.", suffix=".tmp", dir=path.parent)
    os.close(fd)
    os.unlink(name)
    return Path(name)


def replace_path(tmp: Path, path: Path) -> None:
    """Move the finished ``tmp`` onto ``path`` (a folder replaces a folder)."""
    if path.is_dir() and not path.is_symlink():
        old = temp_sibling(path)
        path.rename(old)
        tmp.rename(path)
        shutil.rmtree(old, ignore_errors=True)
    else:
        os.replace(tmp, path)


def remove_path(path: Path) -> None:
    if path.is_dir():
        shutil.rmtree(path, ignore_errors=True)
    elif path.exists():
        path.unlink()


@contextmanager
def atomic_output(path: Path, force: bool = False) -> Iterator[Path]:
    """Yield a temporary path to write; on success it replaces ``path``, on error it is removed."""
    path = Path(path)
    check_writable(path, force)
    tmp = temp_sibling(path)
    try:
        yield tmp
    except BaseException:
        remove_path(tmp)
        raise
    replace_path(tmp, path)


def write_text_atomic(path: Path, text: str, force: bool = False) -> None:
    with atomic_output(path, force) as tmp:
        tmp.write_text(text)
