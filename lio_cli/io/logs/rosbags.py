"""ROS 1 bags and ROS 2 bag folders, read through rosbags' AnyReader."""

from __future__ import annotations

import sqlite3
import struct
from pathlib import Path

from ...errors import InputError
from ...model.records import TopicInfo
from .base import LogConnection, LogReader, RawRecord, first_line, merge_span, read_errors
from .mcap import mcap_channel_spans


class _BagPath(type(Path())):
    """A path that reports the .bag suffix, so rosbags' AnyReader reads it as a ROS 1 bag."""

    @property
    def suffix(self) -> str:
        return ".bag"


class RosbagsLog(LogReader):
    """ROS 1 and ROS 2 bags through rosbags' AnyReader."""

    def __init__(self, path: Path, fmt: str, paths: list[Path]) -> None:
        super().__init__(path, fmt, paths)
        self._conn_cache: dict[int, LogConnection] = {}  # id(rosbags connection) -> its LogConnection
        self._chunks: dict[int, bytes] = {}  # a ROS 1 bag's last decompressed chunks (bag1_raw.messages)
        from rosbags.highlevel import AnyReaderError
        from rosbags.typesys import Stores, get_typestore

        if fmt == "ros1":
            # AnyReader tells ROS 1 from ROS 2 by the .bag suffix; a bag named otherwise is ROS 1 by content
            paths = [p if p.suffix == ".bag" else _BagPath(p) for p in paths]
        try:
            try:
                self._reader = _any_reader(paths, fmt)
                self._reader.open()
            except AnyReaderError as err:
                if "no type definitions" not in str(err):
                    raise
                # an old ROS 2 bag without stored definitions: the standard ones (a typestore built only then)
                default = get_typestore(Stores.ROS2_HUMBLE if fmt == "ros2" else Stores.ROS1_NOETIC)
                self._reader = _any_reader(paths, fmt, default)
                self._reader.open()
        except read_errors() as err:
            raise InputError(
                f"{path}: cannot open as {fmt} log ({first_line(err)}); the log may be truncated or corrupted"
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
        """First and last record time per topic, from the bag index read when the bag was opened."""
        spans: dict[str, tuple[int, int]] = {}
        for conn in self._reader.connections:
            span = conn.owner.spans.get(conn.id)
            if span is not None:
                merge_span(spans, conn.topic, *span)
        return spans

    def _iter_raw(self, topics: set[str] | None, views: bool = False):
        """(topic, msgtype, record time, serialised bytes, rosbags connection) of ``topics`` in record-time
        order; a single ROS 1 bag's straight from its chunks (``bag1_raw``: the same messages; ``views``: as
        views of the chunk where it allows)."""
        conns = [c for c in self._reader.connections if topics is None or c.topic in topics]
        if not conns:
            return iter(())
        readers = getattr(self._reader, "readers", [])
        if self.format == "ros1" and len(readers) == 1:
            from .bag1_raw import messages

            return messages(readers[0], conns, self._chunks, views)
        return ((c.topic, c.msgtype, int(t_ns), raw, c) for c, t_ns, raw in self._reader.messages(connections=conns))

    def _topic_messages(self, topics: list[str], progress) -> dict[str, list[bytes]] | None:
        readers = getattr(self._reader, "readers", [])
        if self.format != "ros1" or len(readers) != 1:
            return None
        conns = [c for c in self._reader.connections if c.topic in topics]
        if len({c.topic for c in conns}) != len(conns):  # a topic on several connections: merged by raw_messages
            return None
        from .bag1_raw import connection_messages

        parts = connection_messages(readers[0], conns, self._chunks, progress)
        return None if parts is None else {c.topic: p for c, p in zip(conns, parts)}

    def _deserialize(self, raw, msgtype, handle):
        return self._reader.deserialize(raw, msgtype)

    def _connections(self) -> list[LogConnection]:
        return [self._connection(c) for c in self._reader.connections]

    def _connection(self, conn) -> LogConnection:
        """The ``LogConnection`` of a rosbags connection (made once per connection)."""
        cache = self._conn_cache
        found = cache.get(id(conn))
        if found is not None:
            return found
        from rosbags.interfaces import ConnectionExtRosbag1, MessageDefinitionFormat

        ext, msgdef = conn.ext, conn.msgdef
        if isinstance(ext, ConnectionExtRosbag1):
            info = LogConnection(len(cache), conn.topic, conn.msgtype, "ros1", msgdef.data, "ros1msg", conn.digest or "",
                                 callerid=ext.callerid, latching=ext.latching)
        else:
            fmt = "ros2idl" if msgdef.format == MessageDefinitionFormat.IDL else "ros2msg"
            info = LogConnection(len(cache), conn.topic, conn.msgtype, "cdr", msgdef.data or "",
                                 fmt if msgdef.data else "", conn.digest or "", qos=tuple(ext.offered_qos_profiles))
        cache[id(conn)] = info
        return info

    def _iter_records(self, topics: set[str] | None):
        for _, _, t_ns, raw, conn in self._iter_raw(topics):
            yield RawRecord(self._connection(conn), t_ns, raw)

    def _deserialize_record(self, rec: RawRecord):
        return self._reader.deserialize(rec.data, rec.connection.msgtype)

    def close(self) -> None:
        try:
            self._reader.close()
        except Exception:  # noqa: BLE001 - closing a broken log must not mask the real error
            pass


def _any_reader(paths: list[Path], fmt: str, default_typestore=None):
    """rosbags' AnyReader; for ROS 1 bags with ``bag1_index``'s reader, which reads the index again when needed."""
    from rosbags.highlevel import AnyReader

    reader = AnyReader(paths, default_typestore=default_typestore)
    if fmt == "ros1":
        from .bag1_index import ChunkIndexReader

        reader.readers = [ChunkIndexReader(p) for p in paths]
    return reader


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
                merge_span(spans, name, int(first), int(last))
        elif storage.suffix == ".mcap":
            from mcap.reader import make_reader

            with storage.open("rb") as f:
                summary = make_reader(f).get_summary()
                if summary is None:
                    continue
                for cid, (first, last) in mcap_channel_spans(f, summary).items():
                    merge_span(spans, summary.channels[cid].topic, first, last)
    return spans


