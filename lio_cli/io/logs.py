"""Open any supported log: ROS 1 bag(s), ROS 2 bag folder (sqlite3 or mcap storage), bare MCAP file.

``open_log`` detects the format from the path (``fmt`` overrides) and returns a ``LogReader`` whose
``messages()`` yields deserialised messages in record-time order, lazily (bounded memory). Every
third-party error is re-raised as ``InputError`` naming the file.
"""

from __future__ import annotations

import sqlite3
from collections.abc import Iterable, Iterator
from pathlib import Path
from typing import Any

from ..errors import InputError
from .records import TopicInfo

FORMATS = ("ros1", "ros2", "mcap")

_ROS1_MAGIC = b"#ROSBAG V2.0"
_MCAP_MAGIC = b"\x89MCAP"
_SQLITE_MAGIC = b"SQLite format 3"


# Corrupted bytes can surface as almost any exception inside rosbags, mcap or sqlite3 (struct.error,
# IndexError, UnicodeDecodeError, their own error classes...). The io boundary turns all of them into
# InputError naming the file; InputError itself passes through untouched.
_READ_ERRORS = (Exception,)


def _magic(path: Path) -> bytes:
    try:
        with path.open("rb") as f:
            return f.read(16)
    except OSError as err:
        raise InputError(f"{path}: cannot read ({err.strerror or err})") from err


def detect_format(path: Path) -> tuple[str, list[Path]]:
    """Return (format, paths to open) for a user-given log path."""
    if not path.exists():
        raise InputError(f"{path}: no such file or folder")
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
    head = _magic(path)
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


class LogReader:
    """A read-only, lazily iterated view of one log."""

    def __init__(self, path: Path, fmt: str, paths: list[Path]) -> None:
        self.path = path
        self.format = fmt
        self.paths = paths
        self.topics: dict[str, TopicInfo] = {}
        self.start_ns: int = 0
        self.end_ns: int = 0

    # subclasses implement these
    def _iter_raw(self, topics: set[str] | None) -> Iterator[tuple[str, str, int, Any, Any]]:
        raise NotImplementedError

    def _deserialize(self, raw: Any, msgtype: str, handle: Any) -> Any:
        raise NotImplementedError

    def close(self) -> None:  # pragma: no cover - trivial
        pass

    def __enter__(self) -> "LogReader":
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    @property
    def duration_ns(self) -> int:
        return max(0, self.end_ns - self.start_ns)

    def _wrap(self, what: str, err: BaseException) -> InputError:
        detail = str(err).strip().splitlines()[0] if str(err).strip() else type(err).__name__
        return InputError(f"{self.path}: {what} ({detail}); the log may be truncated or corrupted")

    def raw_messages(self, topics: Iterable[str] | None = None) -> Iterator[tuple[str, str, int, bytes]]:
        """(topic, msgtype, record_time_ns, serialised bytes) in record-time order."""
        wanted = set(topics) if topics is not None else None
        try:
            for topic, msgtype, t_ns, raw, _ in self._iter_raw(wanted):
                yield topic, msgtype, t_ns, raw
        except InputError:
            raise
        except _READ_ERRORS as err:
            raise self._wrap("cannot read messages", err) from err

    def messages(self, topics: Iterable[str] | None = None) -> Iterator[tuple[str, str, int, Any]]:
        """(topic, msgtype, record_time_ns, message object) in record-time order."""
        wanted = set(topics) if topics is not None else None
        try:
            for topic, msgtype, t_ns, raw, handle in self._iter_raw(wanted):
                yield topic, msgtype, t_ns, self._deserialize(raw, msgtype, handle)
        except InputError:
            raise
        except _READ_ERRORS as err:
            raise self._wrap("cannot read messages", err) from err


class _RosbagsLog(LogReader):
    """ROS 1 and ROS 2 bags through rosbags' AnyReader."""

    def __init__(self, path: Path, fmt: str, paths: list[Path]) -> None:
        super().__init__(path, fmt, paths)
        from rosbags.highlevel import AnyReader
        from rosbags.typesys import Stores, get_typestore

        default = get_typestore(Stores.ROS2_HUMBLE if fmt == "ros2" else Stores.ROS1_NOETIC)
        try:
            self._reader = AnyReader(paths, default_typestore=default)
            self._reader.open()
        except _READ_ERRORS as err:
            raise InputError(f"{path}: cannot open as {fmt} log ({_first_line(err)})") from err
        r = self._reader
        if r.message_count:
            self.start_ns, self.end_ns = int(r.start_time), int(r.end_time)
        counts: dict[str, TopicInfo] = {}
        for conn in r.connections:
            info = counts.setdefault(conn.topic, TopicInfo(conn.topic, conn.msgtype, 0))
            info.count += int(conn.msgcount)
        for info in counts.values():
            info.first_ns, info.last_ns = self.start_ns, self.end_ns
        self.topics = counts

    def _iter_raw(self, topics: set[str] | None):
        conns = [c for c in self._reader.connections if topics is None or c.topic in topics]
        if not conns:
            return
        for conn, t_ns, raw in self._reader.messages(connections=conns):
            yield conn.topic, conn.msgtype, int(t_ns), raw, None

    def _deserialize(self, raw, msgtype, handle):
        return self._reader.deserialize(raw, msgtype)

    def close(self) -> None:
        try:
            self._reader.close()
        except Exception:  # noqa: BLE001 - closing a broken log must not mask the real error
            pass


class _McapLog(LogReader):
    """A bare MCAP file with ROS 2 (CDR) messages, read with the mcap package."""

    def __init__(self, path: Path, fmt: str, paths: list[Path]) -> None:
        super().__init__(path, fmt, paths)
        from mcap.reader import make_reader
        from rosbags.typesys import Stores, get_typestore

        self._typestore = get_typestore(Stores.ROS2_HUMBLE)
        self._registered: set[str] = set()
        try:
            self._file = paths[0].open("rb")
            self._reader = make_reader(self._file)
            summary = self._reader.get_summary()
        except _READ_ERRORS as err:
            raise InputError(f"{path}: cannot open as MCAP ({_first_line(err)})") from err
        if summary is None:
            # No summary section (e.g. a recording cut short): count by scanning once.
            self._scan_without_summary()
            return
        stats = summary.statistics
        if stats is not None and stats.message_count:
            self.start_ns, self.end_ns = int(stats.message_start_time), int(stats.message_end_time)
        counts = stats.channel_message_counts if stats is not None else {}
        for cid, channel in summary.channels.items():
            schema = summary.schemas.get(channel.schema_id)
            msgtype = schema.name if schema else "unknown"
            info = self.topics.setdefault(channel.topic, TopicInfo(channel.topic, msgtype, 0))
            info.count += int(counts.get(cid, 0))
        for info in self.topics.values():
            info.first_ns, info.last_ns = self.start_ns, self.end_ns

    def _scan_without_summary(self) -> None:
        start, end = None, None
        try:
            for schema, channel, message in self._reader.iter_messages(log_time_order=False):
                msgtype = schema.name if schema else "unknown"
                info = self.topics.setdefault(channel.topic, TopicInfo(channel.topic, msgtype, 0))
                info.count += 1
                t = int(message.log_time)
                start = t if start is None else min(start, t)
                end = t if end is None else max(end, t)
        except _READ_ERRORS as err:
            raise InputError(
                f"{self.path}: MCAP file is truncated or corrupted ({_first_line(err)}); re-record or repair it"
            ) from err
        self.start_ns, self.end_ns = start or 0, end or 0
        for info in self.topics.values():
            info.first_ns, info.last_ns = self.start_ns, self.end_ns

    def _iter_raw(self, topics: set[str] | None):
        self._file.seek(0)
        from mcap.reader import make_reader

        reader = make_reader(self._file)
        kwargs = {"topics": sorted(topics)} if topics is not None else {}
        if topics is not None and not topics:
            return
        for schema, channel, message in reader.iter_messages(log_time_order=True, **kwargs):
            if channel.message_encoding != "cdr":
                raise InputError(
                    f"{self.path}: topic {channel.topic} uses '{channel.message_encoding}' encoding; "
                    "lio reads ROS 2 CDR messages only"
                )
            msgtype = schema.name if schema else "unknown"
            yield channel.topic, msgtype, int(message.log_time), message.data, schema

    def _deserialize(self, raw, msgtype, schema):
        if msgtype not in self._typestore.types and msgtype not in self._registered:
            if schema is None or schema.encoding != "ros2msg":
                raise InputError(f"{self.path}: no ROS 2 message definition stored for type {msgtype}")
            from rosbags.typesys import get_types_from_msg

            self._typestore.register(_types_from_ros2msg(schema.data.decode(), msgtype, get_types_from_msg))
            self._registered.add(msgtype)
        return self._typestore.deserialize_cdr(raw, msgtype)

    def close(self) -> None:
        self._file.close()


def _types_from_ros2msg(text: str, name: str, get_types_from_msg) -> dict:
    """Parse a ros2msg schema: the main definition plus '=== MSG: pkg/Type' sub-definitions."""
    types: dict = {}
    parts = text.split("=" * 80)
    types.update(get_types_from_msg(parts[0], name))
    for part in parts[1:]:
        part = part.strip()
        if not part.startswith("MSG:"):
            continue
        header, _, body = part.partition("\n")
        sub = header.split(":", 1)[1].strip()
        if "/msg/" not in sub:
            pkg, _, typ = sub.partition("/")
            sub = f"{pkg}/msg/{typ}"
        types.update(get_types_from_msg(body, sub))
    return types


def _first_line(err: BaseException) -> str:
    text = str(err).strip()
    return text.splitlines()[0] if text else type(err).__name__


def open_log(path: str | Path, fmt: str | None = None) -> LogReader:
    """Open a log for reading. ``fmt`` (ros1, ros2, mcap) overrides detection."""
    path = Path(path)
    detected, paths = detect_format(path)
    if fmt is not None:
        if fmt not in FORMATS:
            raise InputError(f"unknown log format '{fmt}' (choose from {', '.join(FORMATS)})")
        if fmt != detected:
            paths = [path]
        detected = fmt
    if detected == "mcap":
        return _McapLog(path, detected, paths)
    return _RosbagsLog(path, detected, paths)
