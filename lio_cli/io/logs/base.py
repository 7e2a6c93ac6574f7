"""What every log backend shares: the ``LogReader`` base, the records it yields (``LogConnection``,
``RawRecord``), and the errors a damaged log raises, turned into ``InputError`` naming the file."""

from __future__ import annotations

import abc
import functools
import importlib
import re
from collections.abc import Callable, Iterable, Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any, NamedTuple

from ...errors import InputError
from ...model.records import TopicInfo
from ..messages.rawmsg import RAW_PARSERS


@functools.cache
def read_errors() -> tuple[type[BaseException], ...]:
    """The exceptions rosbags, mcap, sqlite3, the decompressors and the raw parsers raise on damaged bytes.

    Caught at the io boundary and re-raised as ``InputError``; anything else is a bug and surfaces as one.
    Built on first use (an ``except`` clause evaluates it only once something was raised)."""
    import sqlite3
    import struct
    import zlib

    from mcap.exceptions import McapError
    from rosbags.highlevel import AnyReaderError
    from rosbags.rosbag1 import ReaderError as Bag1ReaderError
    from rosbags.rosbag2 import ReaderError as Bag2ReaderError
    from rosbags.serde import SerdeError
    from rosbags.typesys import TypesysError

    errors: list[type[BaseException]] = [
        OSError, EOFError, ValueError, KeyError, IndexError, struct.error, zlib.error, sqlite3.Error,
        McapError, AnyReaderError, Bag1ReaderError, Bag2ReaderError, SerdeError, TypesysError,
        RuntimeError,  # lz4.frame's error on a damaged frame
        MemoryError, OverflowError,  # a length field claiming more than there is
    ]  # ValueError holds UnicodeDecodeError and mcap's CRCValidationError
    # rosbags' sqlite3 storage (apsw) and the zstd modules of mcap and rosbags (by Python version)
    for module, name in (("apsw", "Error"), ("zstandard", "ZstdError"), ("backports.zstd", "ZstdError"),
                         ("compression.zstd", "ZstdError")):
        try:
            errors.append(getattr(importlib.import_module(module), name))
        except ImportError:
            pass
    return tuple(errors)


# the definitions (ROS 1 md5, ROS 2 RIHS01) the raw parsers are written for; any other goes to the typestore
_RAW_DIGESTS = {
    "sensor_msgs/msg/PointCloud2": {
        "1158d486dd51d683ce2f1be655c3c181",
        "RIHS01_9198cabf7da3796ae6fe19c4cb3bdd3525492988c70522628af5daa124bae2b5",
    },
    "sensor_msgs/msg/Imu": {
        "6a62c6daae103f4ff57a132d6f95cec2",
        "RIHS01_7d9a00ff131080897a5ec7e26e315954b8eae3353c3f995c55faf71574000b5b",
    },
    "nav_msgs/msg/Odometry": {
        "cd5e73d190d741a2f92e81eda573aca7",
        "RIHS01_3cc97dc7fb7502f8714462c526d369e35b603cfc34d946e3f2eda2766dfec6e0",
    },
    "tf2_msgs/msg/TFMessage": {
        "94810edda583a504dfda3829e70d7eec",
        "RIHS01_e369d0f05a23ae52508854b66f6aa0437f3449d652e8cbf22d5abe85d020f087",
    },
}


@dataclass(frozen=True)
class LogConnection:
    """One connection (ROS bag) or channel (MCAP) of a log, with what a copy needs to recreate it exactly.

    ``encoding``: ``ros1`` or ``cdr``. ``msgdef``: the message definition as stored (``msgdef_format``:
    ``ros1msg``, ``ros2msg``, ``ros2idl``; empty when the log stores none); ``digest``: the ROS 1 md5 or the
    ROS 2 RIHS01 hash ("" when the log has none). ROS 1 bags add ``callerid`` and ``latching``, ROS 2 bags
    their offered QoS profiles (rosbags ``Qos`` objects), MCAP files the channel ``metadata`` and the schema
    name.
    """

    key: int  # unique within the log
    topic: str
    msgtype: str
    encoding: str
    msgdef: str = ""
    msgdef_format: str = ""
    digest: str = ""
    callerid: str | None = None
    latching: int | None = None
    qos: tuple = ()
    metadata: tuple[tuple[str, str], ...] = ()
    schema_name: str = ""

    @property
    def ros1_callerid(self) -> str | None:
        """The ROS 1 caller id: the bag's, or an MCAP channel's ``callerid`` metadata (None when neither says)."""
        return self.callerid if self.callerid is not None else dict(self.metadata).get("callerid")

    @property
    def ros1_latching(self) -> int | None:
        """ROS 1 latching: the bag's, or an MCAP channel's ``latching`` metadata (None when neither says)."""
        if self.latching is not None:
            return self.latching
        value = dict(self.metadata).get("latching", "")
        return int(value) if value.isdigit() else None


class RawRecord(NamedTuple):
    """One message as stored: its connection, record (log) time and serialised bytes; MCAP adds its publish
    time and sequence number."""

    connection: LogConnection
    log_time_ns: int
    data: bytes
    publish_time_ns: int | None = None
    sequence: int | None = None


class LogReader(abc.ABC):
    """A read-only, lazily iterated view of one log; a backend implements the abstract methods."""

    def __init__(self, path: Path, fmt: str, paths: list[Path]) -> None:
        self.path = path
        self.format = fmt
        self.paths = paths
        self.topics: dict[str, TopicInfo] = {}
        self.start_ns: int = 0
        self.end_ns: int = 0

    @abc.abstractmethod
    def _iter_raw(self, topics: set[str] | None, views: bool = False) -> Iterator[tuple[str, str, int, Any, Any]]:
        """(topic, msgtype, record time ns, serialised bytes, decoding handle) of ``topics`` (None: all);
        ``views``: the bytes may be a read-only memoryview into what the backend read (no copy)."""

    @abc.abstractmethod
    def _deserialize(self, raw: Any, msgtype: str, handle: Any) -> Any:
        """The typestore message of bytes ``_iter_raw`` yielded with ``handle``."""

    @abc.abstractmethod
    def _iter_records(self, topics: set[str] | None) -> Iterator[RawRecord]:
        """The ``RawRecord`` of every message of ``topics`` (None: all) in record-time order."""

    @abc.abstractmethod
    def _deserialize_record(self, rec: RawRecord) -> Any:
        """The typestore message of one record."""

    @abc.abstractmethod
    def _connections(self) -> list[LogConnection]:
        """What ``connections`` returns."""

    def close(self) -> None:  # pragma: no cover - trivial
        pass

    def __enter__(self) -> "LogReader":
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    @property
    def connections(self) -> list[LogConnection]:
        """Every connection (channel) of the log, with or without messages, in the log's own order."""
        try:
            return self._connections()
        except InputError:
            raise
        except read_errors() as err:
            raise self._wrap("cannot read its connections", err) from err

    @property
    def duration_ns(self) -> int:
        return max(0, self.end_ns - self.start_ns)

    def _wrap(self, what: str, err: BaseException) -> InputError:
        return InputError(f"{self.path}: {what} ({first_line(err)}); the log may be truncated or corrupted")

    def raw_messages(self, topics: Iterable[str] | None = None) -> Iterator[tuple[str, str, int, bytes]]:
        """(topic, msgtype, record_time_ns, serialised bytes) in record-time order."""
        wanted = set(topics) if topics is not None else None
        try:
            for topic, msgtype, t_ns, raw, _ in self._iter_raw(wanted):
                yield topic, msgtype, t_ns, raw
        except (InputError, GeneratorExit):  # GeneratorExit: closed early (no need to build read_errors)
            raise
        except read_errors() as err:
            raise self._wrap("cannot read messages", err) from err

    def topic_messages(self, topics: Iterable[str],
                       progress: Callable[[int], None] | None = None) -> dict[str, list[bytes]] | None:
        """Every serialised message of each of ``topics``, per topic in the order ``raw_messages`` yields
        them, where the log hands them over a topic at a time faster than ``raw_messages`` (a single ROS 1 bag
        with one connection per topic); None where it does not. ``progress``: messages read so far."""
        try:
            return self._topic_messages(list(topics), progress)
        except InputError:
            raise
        except read_errors() as err:
            raise self._wrap("cannot read messages", err) from err

    def _topic_messages(self, topics: list[str], progress) -> dict[str, list[bytes]] | None:
        return None

    def records(self, topics: Iterable[str] | None = None) -> Iterator[RawRecord]:
        """Every message of ``topics`` (all by default) as stored, with its connection, in record-time order."""
        wanted = set(topics) if topics is not None else None
        try:
            yield from self._iter_records(wanted)
        except (InputError, GeneratorExit):  # GeneratorExit: closed early (no need to build read_errors)
            raise
        except read_errors() as err:
            raise self._wrap("cannot read messages", err) from err

    def deserialize(self, rec: RawRecord) -> Any:
        """The typestore message object of one record (by its connection's stored definition)."""
        try:
            return self._deserialize_record(rec)
        except InputError:
            raise
        except read_errors() as err:
            conn = rec.connection
            raise self._wrap(f"cannot decode a {conn.msgtype} message on {conn.topic}", err) from err

    def decode(self, rec: RawRecord) -> Any:
        """The message of one record as ``messages(fast=True)`` gives it: PointCloud2 and Imu parsed straight
        from their bytes (``RawPointCloud2``, ``RawImu``) when their definition is the standard one, anything
        else by the typestore."""
        conn = rec.connection
        parser = RAW_PARSERS.get(conn.msgtype)
        if parser is not None and (not conn.digest or conn.digest in _RAW_DIGESTS[conn.msgtype]):
            try:
                msg = parser(rec.data, conn.encoding == "cdr")
            except read_errors() as err:
                raise self._wrap(f"cannot decode a {conn.msgtype} message on {conn.topic}", err) from err
            if msg is not None:
                return msg
        return self.deserialize(rec)

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
            for topic, msgtype, t_ns, raw, handle in self._iter_raw(wanted, fast):
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
                        msg = parser(raw, getattr(handle, "cdr", cdr))
                if msg is None:
                    msg = self._deserialize(raw if type(raw) is not memoryview else bytes(raw), msgtype, handle)
                yield topic, msgtype, t_ns, msg
        except (InputError, GeneratorExit):  # GeneratorExit: closed early (no need to build read_errors)
            raise
        except read_errors() as err:
            raise self._wrap("cannot read messages", err) from err


def first_line(err: BaseException) -> str:
    """An exception's first line for a one-line error (its type when it has no text)."""
    text = str(err).strip()
    line = text.splitlines()[0] if text else type(err).__name__
    return re.sub(r"\('(.*)',\)", r"\1", line)  # rosbags wraps messages as "...: ('detail',)"


def merge_span(spans: dict, key, first: int, last: int) -> None:
    """Widen ``spans[key]`` (first, last record time) to take in ``first`` and ``last``."""
    if key in spans:
        f0, l0 = spans[key]
        first, last = min(first, f0), max(last, l0)
    spans[key] = (first, last)
