"""Copy a log's connections and messages into a ``LogWriter``: as stored wherever the output format holds the
input's encoding, converted otherwise.

A ROS 1 bag holds ROS 1 encoded messages, a ROS 2 bag CDR; a bare MCAP file is written with CDR (the ros2
profile, which rosbags and most MCAP tools read) unless the input is itself an MCAP file with ROS 1 encoded
channels, which are then kept so. Messages whose encoding the output holds are copied byte for byte with
their record times (MCAP: publish times and sequence numbers too) on connections that keep the input's
definition, hash and metadata (``LogWriter.add_mirror``). The others (a ROS 1 bag written as a ROS 2 bag or
MCAP file, or back) are converted by rosbags' own converter to the standard definitions of the other ROS
version (a ROS 1 header's ``seq`` is dropped, or added as 0): equal field for field, not byte for byte, and
counted in ``converted``.
"""

from __future__ import annotations

import contextlib
import io
from collections.abc import Callable
from dataclasses import replace

from ..errors import InputError
from .reader import LogConnection, LogReader, RawRecord
from .writer import FORMAT_ENCODINGS, LogWriter, latched_qos


def mcap_profile(reader: LogReader) -> str:
    """The profile of a bare MCAP copy of ``reader``: ``ros1`` for an MCAP file whose channels are all ROS 1
    encoded (kept so), else ``ros2``."""
    conns = reader.connections
    return "ros1" if reader.format == "mcap" and conns and all(c.encoding == "ros1" for c in conns) else "ros2"


class LogCopy:
    """Output connections for a reader's connections, made on first use (or all at once with ``mirror_all``)."""

    def __init__(self, reader: LogReader, writer: LogWriter) -> None:
        self.reader, self.writer = reader, writer
        self._out: dict[tuple[int, str | None], tuple[int, bool]] = {}  # (input key, renamed topic) -> (out key, converted)
        self._converters: dict[int, Callable] = {}  # input key -> bytes converter
        self.copied: dict[str, int] = {}  # messages copied as stored, per topic
        self.converted: dict[str, int] = {}  # messages re-encoded, per topic

    def holds(self, conn: LogConnection) -> bool:
        """The output format holds ``conn``'s encoding (its messages are copied as stored)."""
        if self.writer.format == "mcap" and conn.encoding == "ros1":
            return self.reader.format == "mcap"  # ROS 1 encoded MCAP stays so; a ROS 1 bag becomes ROS 2 MCAP
        return conn.encoding in FORMAT_ENCODINGS[self.writer.format]

    def output(self, conn: LogConnection, topic: str | None = None) -> tuple[int, bool]:
        """(output key, converted) of ``conn``, renamed to ``topic`` when given."""
        found = self._out.get((conn.key, topic))
        if found is None:
            if self.holds(conn):
                found = (self.writer.add_mirror(conn, topic), False)
            else:  # the writer's own encoding and standard definition; the other format's metadata stays behind
                target = replace(conn, encoding=self.writer.encoding, msgdef="", msgdef_format="", digest="",
                                 qos=() if self.writer.encoding == "ros1" else (conn.qos or (
                                     latched_qos() if conn.latching else ())),
                                 callerid=conn.callerid if self.writer.encoding == "ros1" else None,
                                 latching=conn.latching if self.writer.encoding == "ros1" else None)
                found = (self.writer.add_mirror(target, topic), True)
            self._out[(conn.key, topic)] = found
        return found

    def mirror_all(self, skip: set[int] = frozenset()) -> None:
        """Output connections for every input connection (in the input's order) but those keyed in ``skip``,
        so connections without messages are kept too."""
        for conn in self.reader.connections:
            if conn.key not in skip:
                self.output(conn)

    def copy(self, rec: RawRecord, topic: str | None = None) -> None:
        """Write one record on its connection's output (renamed to ``topic`` when given)."""
        key, converted = self.output(rec.connection, topic)
        data = self.convert(rec) if converted else rec.data
        self.writer.write_record(key, rec.log_time_ns, data, rec.publish_time_ns, rec.sequence)
        counts = self.converted if converted else self.copied
        name = topic or rec.connection.topic
        counts[name] = counts.get(name, 0) + 1

    def convert(self, rec: RawRecord) -> bytes:
        """The record's message in the writer's encoding (the standard definition of the other ROS version)."""
        conn = rec.connection
        fn = self._converters.get(conn.key)
        if fn is None:
            fn = self._converters[conn.key] = self._converter(conn)
        try:
            return bytes(fn(rec.data))
        except Exception as err:  # noqa: BLE001 - corrupt bytes surface as any rosbags error
            raise InputError(f"{self.reader.path}: {conn.topic}: cannot convert a {conn.msgtype} message from "
                             f"{conn.encoding} to {self.writer.encoding} encoding ({err})") from err

    def _converter(self, conn: LogConnection) -> Callable:
        from rosbags.convert.converter import generate_message_converter
        from rosbags.typesys import Stores, get_types_from_msg, get_typestore

        src = get_typestore(Stores.ROS1_NOETIC if conn.encoding == "ros1" else Stores.ROS2_HUMBLE)
        dst = self.writer.typestore
        if conn.msgdef and conn.msgdef_format in ("ros1msg", "ros2msg"):  # types the standard stores lack
            try:
                defined = get_types_from_msg(conn.msgdef, conn.msgtype)
            except Exception:  # noqa: BLE001 - an unparsable definition: the standard one must do
                defined = {}
            for store in (src, dst):
                store.register({k: v for k, v in defined.items() if k not in store.types})
        if conn.msgtype not in src.types or conn.msgtype not in dst.types:
            raise InputError(f"{self.reader.path}: {conn.topic}: {conn.msgtype} is not a standard message type, so "
                             f"lio cannot convert it from {conn.encoding} to {self.writer.encoding} encoding; write "
                             "the input's own format instead (--format)")
        with contextlib.redirect_stdout(io.StringIO()):  # rosbags notes each migrated type on stdout
            return generate_message_converter(src, dst, conn.msgtype, conn.msgtype, {},
                                              src_is2=conn.encoding == "cdr", dst_is2=self.writer.encoding == "cdr")
