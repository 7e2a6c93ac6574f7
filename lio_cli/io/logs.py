"""Open any supported log: ROS 1 bag(s), ROS 2 bag folder (sqlite3 or mcap storage), bare MCAP file.

``open_log`` detects the format from the path (``fmt`` overrides) and returns a ``LogReader`` whose
``messages()`` yields deserialised messages in record-time order, lazily (bounded memory). Every
third-party error is re-raised as ``InputError`` naming the file.
"""

from __future__ import annotations

import re
import sqlite3
import struct
from collections.abc import Iterable, Iterator
from pathlib import Path
from typing import Any

from ..errors import InputError
from .rawmsg import RAW_PARSERS
from .records import TopicInfo

FORMATS = ("ros1", "ros2", "mcap")

_ROS1_MAGIC = b"#ROSBAG V2.0"
_MCAP_MAGIC = b"\x89MCAP"
_SQLITE_MAGIC = b"SQLite format 3"


# Corrupted bytes can surface as almost any exception inside rosbags, mcap or sqlite3 (struct.error,
# IndexError, UnicodeDecodeError, their own error classes...). The io boundary turns all of them into
# InputError naming the file; InputError itself passes through untouched.
_READ_ERRORS = (Exception,)

# Definitions the raw parsers (rawmsg.py) are written for: ROS 1 md5 sums and ROS 2 RIHS01 hashes. A log
# whose connection declares another definition of the type is deserialised by the typestore instead.
_RAW_DIGESTS = {
    "sensor_msgs/msg/PointCloud2": {
        "1158d486dd51d683ce2f1be655c3c181",
        "RIHS01_9198cabf7da3796ae6fe19c4cb3bdd3525492988c70522628af5daa124bae2b5",
    },
    "sensor_msgs/msg/Imu": {
        "6a62c6daae103f4ff57a132d6f95cec2",
        "RIHS01_7d9a00ff131080897a5ec7e26e315954b8eae3353c3f995c55faf71574000b5b",
    },
}


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

    def messages(self, topics: Iterable[str] | None = None, *, fast: bool = False
                 ) -> Iterator[tuple[str, str, int, Any]]:
        """(topic, msgtype, record_time_ns, message object) in record-time order.

        ``fast``: PointCloud2 and Imu messages are parsed straight from their bytes (``rawmsg``) into light
        records (``RawPointCloud2``, ``RawImu``) instead of typestore objects; other types are unchanged.
        """
        wanted = set(topics) if topics is not None else None
        cdr = self.format != "ros1"
        parsers: dict = {}
        try:
            for topic, msgtype, t_ns, raw, handle in self._iter_raw(wanted):
                msg = None
                if fast:
                    key = (msgtype, getattr(handle, "digest", "") or "")
                    parser = parsers.get(key, 0)
                    if parser == 0:
                        parser = RAW_PARSERS.get(msgtype)
                        if parser is not None and key[1] and key[1] not in _RAW_DIGESTS[msgtype]:
                            parser = None
                        parsers[key] = parser
                    if parser is not None:
                        msg = parser(raw, cdr)
                if msg is None:
                    msg = self._deserialize(raw, msgtype, handle)
                yield topic, msgtype, t_ns, msg
        except InputError:
            raise
        except _READ_ERRORS as err:
            raise self._wrap("cannot read messages", err) from err


class _BagPath(type(Path())):
    """A path that reports the .bag suffix, so rosbags' AnyReader reads it as a ROS 1 bag."""

    @property
    def suffix(self) -> str:
        return ".bag"


class _RosbagsLog(LogReader):
    """ROS 1 and ROS 2 bags through rosbags' AnyReader."""

    def __init__(self, path: Path, fmt: str, paths: list[Path]) -> None:
        super().__init__(path, fmt, paths)
        from rosbags.highlevel import AnyReader, AnyReaderError
        from rosbags.typesys import Stores, get_typestore

        if fmt == "ros1":
            # AnyReader tells ROS 1 from ROS 2 by the .bag suffix; a bag named otherwise is ROS 1 by content
            paths = [p if p.suffix == ".bag" else _BagPath(p) for p in paths]
        try:
            try:
                self._reader = AnyReader(paths)
                self._reader.open()
            except AnyReaderError as err:
                if "no type definitions" not in str(err):
                    raise
                # an old ROS 2 bag without stored definitions: use the standard ones (building a default
                # typestore costs ~50 ms, so only when needed)
                default = get_typestore(Stores.ROS2_HUMBLE if fmt == "ros2" else Stores.ROS1_NOETIC)
                self._reader = AnyReader(paths, default_typestore=default)
                self._reader.open()
        except _READ_ERRORS as err:
            raise InputError(
                f"{path}: cannot open as {fmt} log ({_first_line(err)}); the log may be truncated or corrupted"
            ) from err
        r = self._reader
        if r.message_count:
            # rosbags' end_time is one past the last message
            self.start_ns, self.end_ns = int(r.start_time), int(r.end_time) - 1
        counts: dict[str, TopicInfo] = {}
        for conn in r.connections:
            info = counts.setdefault(conn.topic, TopicInfo(conn.topic, conn.msgtype, 0))
            info.count += int(conn.msgcount)
        try:
            spans = self._ros1_spans() if fmt == "ros1" else _ros2_spans(paths[0])
        except (OSError, sqlite3.Error, struct.error, ValueError, KeyError, TypeError, AttributeError):
            spans = {}  # per-topic spans are a nicety for rates; the log's own span stands in
        for info in counts.values():
            first, last = spans.get(info.name, (self.start_ns, self.end_ns))
            info.first_ns, info.last_ns = (first, last) if info.count else (None, None)
        self.topics = counts

    def _ros1_spans(self) -> dict[str, tuple[int, int]]:
        """First and last record time per topic, from the bag index rosbags already holds in memory."""
        spans: dict[str, tuple[int, int]] = {}
        for conn in self._reader.connections:
            idx = conn.owner.indexes.get(conn.id)
            if idx:
                _merge_span(spans, conn.topic, int(idx[0].time), int(idx[-1].time))
        return spans

    def _iter_raw(self, topics: set[str] | None):
        conns = [c for c in self._reader.connections if topics is None or c.topic in topics]
        if not conns:
            return
        for conn, t_ns, raw in self._reader.messages(connections=conns):
            yield conn.topic, conn.msgtype, int(t_ns), raw, conn

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

        self._typestore = None  # built from the file's schemas on first deserialisation
        self._registered: set[str] = set()
        try:
            self._file = paths[0].open("rb")
            self._reader = make_reader(self._file, validate_crcs=True)
            summary = self._reader.get_summary()
        except _READ_ERRORS as err:
            raise InputError(
                f"{path}: cannot open as MCAP ({_first_line(err)}); the file may be truncated or corrupted"
            ) from err
        if summary is None or summary.statistics is None:
            # No summary section or no statistics (legal in MCAP): count by scanning once.
            self._scan_without_summary()
            return
        stats = summary.statistics
        if stats.message_count:
            self.start_ns, self.end_ns = int(stats.message_start_time), int(stats.message_end_time)
        counts = stats.channel_message_counts
        try:
            spans = _mcap_channel_spans(self._file, summary)
        except (OSError, struct.error, ValueError):
            spans = {}
        for cid, channel in summary.channels.items():
            schema = summary.schemas.get(channel.schema_id)
            msgtype = schema.name if schema else "unknown"
            info = self.topics.setdefault(channel.topic, TopicInfo(channel.topic, msgtype, 0))
            info.count += int(counts.get(cid, 0))
            if cid in spans:
                first, last = spans[cid]
                info.first_ns = first if info.first_ns is None else min(info.first_ns, first)
                info.last_ns = last if info.last_ns is None else max(info.last_ns, last)
        for info in self.topics.values():
            if info.count and info.first_ns is None:
                info.first_ns, info.last_ns = self.start_ns, self.end_ns

    def _scan_without_summary(self) -> None:
        start, end = None, None
        try:
            self._file.seek(0)
            from mcap.reader import make_reader

            reader = make_reader(self._file, validate_crcs=True)
            for schema, channel, message in reader.iter_messages(log_time_order=False):
                msgtype = schema.name if schema else "unknown"
                info = self.topics.setdefault(channel.topic, TopicInfo(channel.topic, msgtype, 0))
                info.count += 1
                t = int(message.log_time)
                info.first_ns = t if info.first_ns is None else min(info.first_ns, t)
                info.last_ns = t if info.last_ns is None else max(info.last_ns, t)
                start = t if start is None else min(start, t)
                end = t if end is None else max(end, t)
        except _READ_ERRORS as err:
            raise InputError(
                f"{self.path}: MCAP file is truncated or corrupted ({_first_line(err)}); re-record or repair it"
            ) from err
        self.start_ns, self.end_ns = start or 0, end or 0

    def _iter_raw(self, topics: set[str] | None):
        self._file.seek(0)
        from mcap.reader import make_reader

        reader = make_reader(self._file, validate_crcs=True)
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
        if self._typestore is None:
            from rosbags.typesys import Stores, get_typestore

            self._typestore = get_typestore(Stores.EMPTY)
        if msgtype not in self._registered:
            if schema is None or schema.encoding != "ros2msg":
                if msgtype not in self._typestore.types:  # no definition in the file: the standard one
                    from rosbags.typesys import Stores, get_typestore

                    self._typestore.register(get_typestore(Stores.ROS2_HUMBLE).fielddefs)
                if msgtype not in self._typestore.types:
                    raise InputError(f"{self.path}: no ROS 2 message definition stored for type {msgtype}")
            else:
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


def _merge_span(spans: dict, key, first: int, last: int) -> None:
    if key in spans:
        f0, l0 = spans[key]
        first, last = min(first, f0), max(last, l0)
    spans[key] = (first, last)


def _ros2_spans(folder: Path) -> dict[str, tuple[int, int]]:
    """First and last record time per topic of a ROS 2 bag, from its storage files' indexes.

    sqlite3: one aggregate query (it touches row headers, not message blobs; rosbags' own open does the
    same to count). mcap: chunk and message indexes. Compressed bags ('file' mode) give no spans.
    """
    import yaml

    meta = yaml.safe_load((folder / "metadata.yaml").read_text())["rosbag2_bagfile_information"]
    if meta.get("compression_mode", "") == "file":
        return {}
    spans: dict[str, tuple[int, int]] = {}
    for rel in meta.get("relative_file_paths", []):
        storage = folder / rel
        if storage.suffix == ".db3":
            con = sqlite3.connect(f"{storage.resolve().as_uri()}?mode=ro", uri=True)
            try:
                rows = con.execute(
                    "SELECT topics.name, min(messages.timestamp), max(messages.timestamp) FROM messages "
                    "JOIN topics ON messages.topic_id = topics.id GROUP BY topics.name"
                ).fetchall()
            finally:
                con.close()
            for name, first, last in rows:
                _merge_span(spans, name, int(first), int(last))
        elif storage.suffix == ".mcap":
            from mcap.reader import make_reader

            with storage.open("rb") as f:
                summary = make_reader(f).get_summary()
                if summary is None:
                    continue
                for cid, (first, last) in _mcap_channel_spans(f, summary).items():
                    _merge_span(spans, summary.channels[cid].topic, first, last)
    return spans


def _mcap_message_index_times(f, offset: int) -> list[int]:
    """Log times listed in the MessageIndex record at ``offset``."""
    f.seek(offset)
    head = f.read(9)
    opcode, length = head[0], struct.unpack("<Q", head[1:9])[0]
    if opcode != 0x07 or length > 1 << 32:
        raise ValueError(f"no message index at offset {offset}")
    body = f.read(length)
    (nbytes,) = struct.unpack_from("<I", body, 2)
    return [t for t, _ in struct.iter_unpack("<QQ", body[6 : 6 + nbytes])]


def _mcap_channel_spans(f, summary) -> dict[int, tuple[int, int]]:
    """First and last log time per channel id, reading the message indexes of the few edge chunks only."""
    spans: dict[int, tuple[int, int]] = {}
    chunks = list(summary.chunk_indexes)
    for cid in summary.channels:
        have = [c for c in chunks if cid in c.message_index_offsets]
        if not have:
            continue
        first = last = None
        for c in sorted(have, key=lambda c: c.message_start_time):
            if first is not None and c.message_start_time > first:
                break
            times = _mcap_message_index_times(f, c.message_index_offsets[cid])
            if times:
                first = min(times) if first is None else min(first, min(times))
        for c in sorted(have, key=lambda c: c.message_end_time, reverse=True):
            if last is not None and c.message_end_time < last:
                break
            times = _mcap_message_index_times(f, c.message_index_offsets[cid])
            if times:
                last = max(times) if last is None else max(last, max(times))
        if first is not None and last is not None:
            spans[cid] = (first, last)
    return spans


def _first_line(err: BaseException) -> str:
    text = str(err).strip()
    line = text.splitlines()[0] if text else type(err).__name__
    return re.sub(r"\('(.*)',\)", r"\1", line)  # rosbags wraps messages as "...: ('detail',)"


def _paths_for(path: Path, fmt: str) -> list[Path]:
    """What to open for a format forced with ``--format`` (no content sniffing)."""
    if not path.exists():
        raise InputError(f"{path}: no such file or folder")
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


def open_log(path: str | Path, fmt: str | None = None) -> LogReader:
    """Open a log for reading. ``fmt`` (ros1, ros2, mcap) overrides detection."""
    path = Path(path)
    if fmt is None:
        detected, paths = detect_format(path)
    else:
        if fmt not in FORMATS:
            raise InputError(f"unknown log format '{fmt}' (choose from {', '.join(FORMATS)})")
        detected, paths = fmt, _paths_for(path, fmt)
    if detected == "mcap":
        return _McapLog(path, detected, paths)
    return _RosbagsLog(path, detected, paths)
