"""Bare MCAP files, read with the mcap package: ROS 2 (CDR) or ROS 1 encoded messages; MCAP index helpers.

Type names are given the ``pkg/msg/Type`` form whatever the encoding (ROS 1 schemas say ``pkg/Type``).
"""

from __future__ import annotations

import struct
from pathlib import Path
from typing import NamedTuple

from ...errors import InputError
from ...model.records import TopicInfo
from ..messages.msgdefs import types_of_definition
from .base import LogConnection, LogReader, RawRecord, first_line, read_errors

_ENCODINGS = ("cdr", "ros1")


class _Handle(NamedTuple):
    """What ``messages`` needs to decode one channel's bytes."""

    schema: object
    encoding: str  # cdr or ros1

    @property
    def cdr(self) -> bool:
        return self.encoding == "cdr"


def _msgtype(schema) -> str:
    """``pkg/msg/Type`` of a schema (ROS 1 schemas name ``pkg/Type``)."""
    if schema is None:
        return "unknown"
    name = schema.name
    if "/msg/" not in name and name.count("/") == 1:
        pkg, _, typ = name.partition("/")
        name = f"{pkg}/msg/{typ}"
    return name


class McapLog(LogReader):
    """A bare MCAP file with ROS 2 (CDR) or ROS 1 encoded messages, read with the mcap package."""

    def __init__(self, path: Path, fmt: str, paths: list[Path]) -> None:
        super().__init__(path, fmt, paths)
        from mcap.reader import make_reader

        self._typestores: dict[str, object] = {}  # per encoding, built from the file's schemas when needed
        self._registered: set[tuple[str, str]] = set()
        self._channels: dict[int, tuple[LogConnection, _Handle]] = {}  # channel id -> its connection
        self._summary = None
        try:
            self._file = paths[0].open("rb")
            self._reader = make_reader(self._file, validate_crcs=True)
            summary = self._reader.get_summary()
        except read_errors() as err:
            raise InputError(
                f"{path}: cannot open as MCAP ({first_line(err)}); the file may be truncated or corrupted"
            ) from err
        self._summary = summary
        if summary is None or summary.statistics is None:
            # No summary section or no statistics (legal in MCAP): count by scanning once.
            self._scan_without_summary()
            return
        stats = summary.statistics
        if stats.message_count:
            self.start_ns, self.end_ns = int(stats.message_start_time), int(stats.message_end_time)
        counts = stats.channel_message_counts
        try:
            spans = mcap_channel_spans(self._file, summary)
        except read_errors():  # per-channel spans are a nicety for rates; the file's own span stands in
            spans = {}
        for cid, channel in summary.channels.items():
            msgtype = _msgtype(summary.schemas.get(channel.schema_id))
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
                msgtype = _msgtype(schema)
                info = self.topics.setdefault(channel.topic, TopicInfo(channel.topic, msgtype, 0))
                info.count += 1
                t = int(message.log_time)
                info.first_ns = t if info.first_ns is None else min(info.first_ns, t)
                info.last_ns = t if info.last_ns is None else max(info.last_ns, t)
                start = t if start is None else min(start, t)
                end = t if end is None else max(end, t)
        except read_errors() as err:
            raise InputError(
                f"{self.path}: MCAP file is truncated or corrupted ({first_line(err)}); re-record or repair it"
            ) from err
        self.start_ns, self.end_ns = start or 0, end or 0

    def _iter_raw(self, topics: set[str] | None, views: bool = False):
        self._file.seek(0)
        from mcap.reader import make_reader

        reader = make_reader(self._file, validate_crcs=True)
        kwargs = {"topics": sorted(topics)} if topics is not None else {}
        if topics is not None and not topics:
            return
        for schema, channel, message in reader.iter_messages(log_time_order=True, **kwargs):
            if channel.message_encoding not in _ENCODINGS:
                raise InputError(
                    f"{self.path}: topic {channel.topic} uses '{channel.message_encoding}' encoding; "
                    "lio reads ROS 2 (cdr) and ROS 1 (ros1) messages"
                )
            yield channel.topic, _msgtype(schema), int(message.log_time), message.data, \
                _Handle(schema, channel.message_encoding)

    def _channel(self, schema, channel) -> tuple[LogConnection, _Handle]:
        """The ``LogConnection`` (and decoding handle) of an MCAP channel, made once per channel."""
        found = self._channels.get(channel.id)
        if found is None:
            text, fmt = "", ""
            if schema is not None and schema.encoding in ("ros1msg", "ros2msg", "ros2idl"):
                text, fmt = schema.data.decode(), schema.encoding
            conn = LogConnection(channel.id, channel.topic, _msgtype(schema), channel.message_encoding, text, fmt,
                                 metadata=tuple(sorted(channel.metadata.items())),
                                 schema_name=schema.name if schema is not None else "")
            found = self._channels[channel.id] = (conn, _Handle(schema, channel.message_encoding))
        return found

    def _connections(self) -> list[LogConnection]:
        summary = self._summary
        if summary is None:  # no summary section: the channels met so far (all of them after one pass)
            return [c for c, _ in self._channels.values()]
        return [self._channel(summary.schemas.get(ch.schema_id), ch)[0]
                for _, ch in sorted(summary.channels.items())]

    def _iter_records(self, topics: set[str] | None):
        self._file.seek(0)
        from mcap.reader import make_reader

        if topics is not None and not topics:
            return
        reader = make_reader(self._file, validate_crcs=True)
        kwargs = {"topics": sorted(topics)} if topics is not None else {}
        for schema, channel, message in reader.iter_messages(log_time_order=True, **kwargs):
            if channel.message_encoding not in _ENCODINGS:
                raise InputError(
                    f"{self.path}: topic {channel.topic} uses '{channel.message_encoding}' encoding; "
                    "lio reads ROS 2 (cdr) and ROS 1 (ros1) messages"
                )
            conn, _ = self._channel(schema, channel)
            yield RawRecord(conn, int(message.log_time), message.data, int(message.publish_time),
                            int(message.sequence))

    def _deserialize_record(self, rec: RawRecord):
        _, handle = self._channels[rec.connection.key]
        return self._deserialize(rec.data, rec.connection.msgtype, handle)

    def _deserialize(self, raw, msgtype, handle: _Handle):
        from rosbags.typesys import Stores, get_typestore

        ros1 = handle.encoding == "ros1"
        store = self._typestores.get(handle.encoding)
        if store is None:
            store = self._typestores[handle.encoding] = get_typestore(Stores.EMPTY)
        schema = handle.schema
        if (handle.encoding, msgtype) not in self._registered:
            if schema is not None and schema.encoding in ("ros2msg", "ros1msg", "ros2idl"):
                store.register(types_of_definition(schema.data.decode(), schema.encoding, msgtype))
            elif msgtype not in store.types:  # no definition in the file: the standard one
                store.register(get_typestore(Stores.ROS1_NOETIC if ros1 else Stores.ROS2_HUMBLE).fielddefs)
            if msgtype not in store.types:
                raise InputError(f"{self.path}: no {'ROS 1' if ros1 else 'ROS 2'} message definition stored "
                                 f"for type {msgtype}")
            self._registered.add((handle.encoding, msgtype))
        return store.deserialize_ros1(raw, msgtype) if ros1 else store.deserialize_cdr(raw, msgtype)

    def close(self) -> None:
        self._file.close()


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


def mcap_channel_spans(f, summary) -> dict[int, tuple[int, int]]:
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


