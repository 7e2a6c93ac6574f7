"""Which log format a path holds, and which files to open for it (content first, then names)."""

from __future__ import annotations

from pathlib import Path

from ...errors import InputError

FORMATS = ("ros1", "ros2", "mcap")

_ROS1_MAGIC = b"#ROSBAG V2.0"
_MCAP_MAGIC = b"\x89MCAP"
_SQLITE_MAGIC = b"SQLite format 3"


def magic(path: Path) -> bytes:
    try:
        with path.open("rb") as f:
            return f.read(16)
    except OSError as err:
        raise InputError(f"{path}: cannot read ({err.strerror or err})") from err


def _require_file_or_folder(path: Path) -> None:
    """Refuse before opening anything that is neither a regular file nor a folder: a FIFO or a device would block
    or stream forever."""
    if not path.exists():
        raise InputError(f"{path}: no such file or folder")
    if not (path.is_dir() or path.is_file()):
        raise InputError(f"{path}: not a regular file or folder (a FIFO, socket or device cannot be a log)")


def looks_like_log(path: Path) -> bool:
    """A folder, or a file that starts like a ROS 1 bag, an MCAP file or a sqlite3 database."""
    if path.is_dir():
        return True
    if not path.is_file():
        return False
    try:
        with path.open("rb") as f:
            head = f.read(16)
    except OSError:
        return False
    return head.startswith((_ROS1_MAGIC, _MCAP_MAGIC, _SQLITE_MAGIC))


def detect_format(path: Path) -> tuple[str, list[Path]]:
    """Return (format, paths to open) for a user-given log path."""
    _require_file_or_folder(path)
    if path.is_dir():
        if (path / "metadata.yaml").exists():
            return "ros2", [path]
        bags = sorted(path.glob("*.bag"))
        if bags:
            return "ros1", bags
        mcaps = sorted(path.glob("*.mcap"))
        if len(mcaps) == 1:
            return "mcap", mcaps
        raise InputError(
            f"{path}: folder holds no log (expected a ROS 2 bag with metadata.yaml, .bag files or one .mcap)"
        )
    if path.name == "metadata.yaml":
        return "ros2", [path.parent]
    head = magic(path)
    if head.startswith(_ROS1_MAGIC):
        return "ros1", [path]
    if head.startswith(_MCAP_MAGIC):
        if (path.parent / "metadata.yaml").exists():
            return "ros2", [path.parent]
        return "mcap", [path]
    if head.startswith(_SQLITE_MAGIC) and (path.parent / "metadata.yaml").exists():
        return "ros2", [path.parent]
    if not head:
        raise InputError(f"{path}: file is empty, not a log")
    raise InputError(f"{path}: not a ROS 1 bag, ROS 2 bag or MCAP file (unrecognised content)")


def paths_for(path: Path, fmt: str) -> list[Path]:
    """What to open for a format forced with ``--format`` (no content sniffing)."""
    _require_file_or_folder(path)
    if fmt == "ros1":
        if path.is_dir():
            bags = sorted(path.glob("*.bag"))
            if not bags:
                raise InputError(f"{path}: folder holds no .bag files to read as ROS 1")
            return bags
        return [path]
    if fmt == "ros2":
        folder = path if path.is_dir() else path.parent
        if not (folder / "metadata.yaml").exists():
            raise InputError(f"{path}: a ROS 2 bag needs its folder with metadata.yaml; none found in {folder}")
        return [folder]
    if path.is_dir():
        mcaps = sorted(path.glob("*.mcap"))
        if len(mcaps) != 1:
            raise InputError(f"{path}: give the .mcap file itself (the folder holds {len(mcaps)} .mcap files)")
        return mcaps
    return [path]


def input_paths(log: Path) -> list[Path]:
    """Every path a log occupies: the path given, and the bag folder when a ROS 2 bag was named by a file in it."""
    log = Path(log)
    out = [log]
    if not log.is_dir() and (log.parent / "metadata.yaml").exists():
        out.append(log.parent)
    return out
