"""Open any supported log: ROS 1 bag(s), ROS 2 bag folder (sqlite3 or mcap storage), bare MCAP file.

``open_log`` detects the format from the path (``fmt`` overrides) and returns the backend's ``LogReader``
(``base``): ``mcap.McapLog`` for a bare MCAP file, ``rosbags.RosbagsLog`` for ROS 1 and ROS 2 bags.
"""

from __future__ import annotations

from pathlib import Path

from ...errors import InputError
from .base import LogReader
from .detect import FORMATS, detect_format, paths_for
from .mcap import McapLog
from .rosbags import RosbagsLog

_FORMAT_NAMES = {"ros1": "a ROS 1 bag", "ros2": "a ROS 2 bag", "mcap": "an MCAP file"}


def _check_asked_format(path: Path, fmt: str) -> None:
    """A format asked for that the log's content contradicts (a ROS 1 bag read as MCAP or ROS 2, or the other
    way) is one clear line, not "cannot open ... truncated or corrupted"; reading a ROS 2 bag's .mcap file as
    bare MCAP stays possible, and content detection cannot tell does not stop the format asked for."""
    try:
        found, _ = detect_format(path)
    except InputError:
        return
    if found != fmt and "ros1" in (found, fmt):
        raise InputError(f"{path}: is {_FORMAT_NAMES[found]}, not {_FORMAT_NAMES[fmt]} as asked (--format, "
                         "--input-format or input.format in --config; a .config.yaml written before this release "
                         "pins the format it found: make it null)")


def open_log(path: str | Path, fmt: str | None = None) -> LogReader:
    """Open a log for reading. ``fmt`` (ros1, ros2, mcap) overrides detection."""
    path = Path(path)
    if fmt is None:
        detected, paths = detect_format(path)
    else:
        if fmt not in FORMATS:
            raise InputError(f"unknown log format '{fmt}' (choose from {', '.join(FORMATS)})")
        _check_asked_format(path, fmt)
        detected, paths = fmt, paths_for(path, fmt)
    if detected == "mcap":
        return McapLog(path, detected, paths)
    return RosbagsLog(path, detected, paths)
