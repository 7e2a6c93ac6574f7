"""Bare MCAP files (ROS 2 CDR messages), read with the mcap package; MCAP index helpers."""

from __future__ import annotations

import struct
from pathlib import Path

from ..errors import InputError
from ..model.records import TopicInfo
from .reader import _READ_ERRORS, LogReader, _first_line

class McapLog(LogReader):
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
            spans = mcap_channel_spans(self._file, summary)
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


