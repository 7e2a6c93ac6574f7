"""Atomic outputs: write to a temporary sibling, then rename; never clobber without ``force``."""

from __future__ import annotations

import errno
import os
import shutil
import tempfile
from collections.abc import Callable, Iterable, Iterator
from contextlib import contextmanager
from pathlib import Path

from ...errors import InputError, NoSpaceError


def check_writable(path: Path, force: bool, inputs: Iterable[Path] = (),
                   replaceable: Callable[[Path], bool] | None = None) -> None:
    """Before any work: ``path`` is no input (``--force`` or not), may be replaced, and its folder takes files.

    Refused: an output that is one of ``inputs`` (same path, same file through a link), lies inside an input
    folder, or is a folder holding an input; an existing output without ``force``; a folder that does not
    exist, is not a folder, or cannot be written (read-only file system, /proc, no permission). An existing
    folder is replaced only when ``replaceable(folder)`` says it is one lio wrote (default: a ROS 2 bag).
    """
    path = Path(path)
    for inp in inputs:
        _refuse_input(path, Path(inp))
    if path.exists() and not force:
        raise InputError(f"{path}: already exists; pass --force to overwrite it")
    if path.is_dir() and not path.is_symlink() and not (replaceable or is_ros2_bag_folder)(path):
        what = "a ROS 2 bag" if replaceable is None else "an output"
        raise InputError(f"{path}: is a folder that is not {what} lio wrote; lio replaces only such folders, "
                         "even with --force: choose another output")
    parent = path.parent
    if not parent.exists():
        raise InputError(f"{parent}: output folder does not exist")
    if not parent.is_dir():
        raise InputError(f"{parent}: is not a folder, so {path.name} cannot be written there")
    try:  # the only reliable test of writability: create a file there
        fd, probe = tempfile.mkstemp(prefix=f".{path.name}.", suffix=".probe", dir=parent)
    except OSError as err:
        raise InputError(f"{path}: cannot write there ({err.strerror or err})") from err
    os.close(fd)
    os.unlink(probe)


def is_ros2_bag_folder(path: Path) -> bool:
    """A folder output may replace only a ROS 2 bag folder: metadata.yaml plus its storage files, nothing else."""
    names = {p.name for p in path.iterdir()}
    if "metadata.yaml" not in names:
        return not names  # an empty folder holds nothing to lose
    return all(n == "metadata.yaml" or n.endswith((".db3", ".mcap", ".db3-shm", ".db3-wal")) for n in names)


def _refuse_input(out: Path, inp: Path) -> None:
    if not inp.exists():
        return
    out_real, inp_real = os.path.realpath(out), os.path.realpath(inp)
    same = out_real == inp_real or (out.exists() and os.path.samefile(out, inp))
    inside = inp.is_dir() and out_real.startswith(inp_real.rstrip(os.sep) + os.sep)
    holds = out.is_dir() and inp_real.startswith(out_real.rstrip(os.sep) + os.sep)
    if same or inside or holds:
        what = "the input" if same else "inside the input folder" if inside else "a folder holding the input"
        raise InputError(f"{out}: is an input of this run ({what} {inp}); lio never writes over its inputs, "
                         "whatever the options: choose another output")


_placed: list[tuple[Path, bool]] | None = None  # (output or folder made, is a made folder), while a run keeps count


def keep_count() -> None:
    """From now on remember every output put in place and every folder made, so ``take_back`` can remove them
    (one CLI command; not a batch, whose finished runs stay when it is stopped)."""
    global _placed
    _placed = []


def take_back() -> None:
    """Remove what this run has put in place, newest first (a folder it made only once empty): an interrupted
    run leaves nothing, not the first of its files."""
    global _placed
    placed, _placed = _placed or [], None
    for path, made in reversed(placed):
        try:
            if made:
                path.rmdir()
            else:
                remove_path(path)
        except OSError:
            pass


def make_folder(path: Path) -> Path:
    """``path`` as a folder (parents too); the ones made here count as outputs (``take_back``)."""
    path = Path(path)
    missing = [p for p in (path, *path.parents) if not p.exists()]
    path.mkdir(parents=True, exist_ok=True)
    if _placed is not None:
        _placed.extend((p, True) for p in reversed(missing))
    return path


def temp_sibling(path: Path) -> Path:
    """A fresh unused path beside ``path`` (same filesystem, so the final rename is atomic)."""
    fd, name = tempfile.mkstemp(prefix=f".{path.name}.", suffix=".tmp", dir=path.parent)
    os.close(fd)
    os.unlink(name)
    return Path(name)


def replace_path(tmp: Path, path: Path) -> None:
    """Move the finished ``tmp`` onto ``path`` (a folder replaces a folder)."""
    if _placed is not None:
        _placed.append((Path(path), False))
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


def is_no_space(err: BaseException) -> bool:
    """``err`` says the device is full: ENOSPC, EDQUOT, or sqlite's (and so a ROS 2 bag's) own words."""
    return (isinstance(err, OSError) and err.errno in (errno.ENOSPC, errno.EDQUOT)) or \
        "database or disk is full" in str(err)


def no_space_error(err: BaseException, path: Path) -> NoSpaceError | None:
    """``NoSpaceError`` naming ``path`` when ``err`` (or the error it wraps) says the device is full, else None."""
    if is_no_space(err) or is_no_space(err.__cause__ or err.__context__ or err):
        return NoSpaceError(f"no space left on device: {path}")
    return None


@contextmanager
def no_space_as_error(path: Path) -> Iterator[None]:
    """A full device met in the body becomes ``NoSpaceError`` naming ``path`` (one line, exit 1)."""
    try:
        yield
    except NoSpaceError:
        raise
    except Exception as err:
        full = no_space_error(err, path)
        if full is not None:
            raise full from err
        raise


@contextmanager
def atomic_output(path: Path, force: bool = False) -> Iterator[Path]:
    """Yield a temporary path to write; on success it replaces ``path``, on error it is removed."""
    with atomic_outputs([path], force) as (tmp,):
        yield tmp


@contextmanager
def atomic_outputs(paths: Iterable[Path], force: bool = False) -> Iterator[list[Path]]:
    """Yield a temporary path for each of ``paths``; once every one is written they replace ``paths`` together,
    on error (a full device too) every one is removed: a run's files are all there or none is."""
    paths = [Path(p) for p in paths]
    for path in paths:
        check_writable(path, force)
    tmps: list[Path] = []
    try:
        with no_space_as_error(paths[0]):
            tmps.extend(temp_sibling(path) for path in paths)
            yield tmps
    except BaseException:
        for tmp in tmps:
            remove_path(tmp)
        raise
    for tmp, path in zip(tmps, paths):
        replace_path(tmp, path)


def write_text_atomic(path: Path, text: str, force: bool = False) -> None:
    with atomic_output(path, force) as tmp:
        tmp.write_text(text)
