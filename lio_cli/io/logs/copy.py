"""Copy a log's connections and messages into a ``LogWriter``: as stored wherever the output format holds the
input's encoding, converted otherwise.

A ROS 1 bag holds ROS 1 encoded messages, a ROS 2 bag CDR; a bare MCAP file is written with CDR (the ros2
profile, which rosbags' AnyReader and most MCAP tools read; AnyReader refuses the ros1 profile), so the ROS 1
encoded channels of an MCAP input are converted there too. Messages whose encoding the output holds are copied
byte for byte with their record times (MCAP: publish times and sequence numbers too) on connections that keep
the input's definition, hash (computed from the definition where the input has none: MCAP) and metadata
(``LogWriter.add_mirror``). The others (ROS 1 written as ROS 2 or MCAP, or back) are converted by rosbags' own
converter from the input's stored definition (the standard one where it stores none) to the other ROS
version's standard definition, or, for a type that version lacks (a driver's own), to the input's definition
in the other version's form (a ROS 1 header's ``seq`` is dropped, or added as 0): equal field for field, not
byte for byte, and counted in ``converted``.
"""

from __future__ import annotations

import contextlib
import io
from collections.abc import Callable
from dataclasses import replace

from ...errors import InputError
from ..messages.msgdefs import stored_typestore
from .base import LogConnection, LogReader, RawRecord, first_line, read_errors
from .writer import FORMAT_ENCODINGS, LogWriter, latched_qos


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
        return conn.encoding in FORMAT_ENCODINGS[self.writer.format]

    def output(self, conn: LogConnection, topic: str | None = None) -> tuple[int, bool]:
        """(output key, converted) of ``conn``, renamed to ``topic`` when given."""
        found = self._out.get((conn.key, topic))
        if found is None:
            if self.holds(conn):
                found = (self.writer.add_mirror(conn, topic), False)
            else:  # the writer's encoding and definition; the other format's metadata stays behind
                if conn.key not in self._converters:  # first: it gives the writer's typestore the input's own types
                    self._converters[conn.key] = self._converter(conn)
                ros1 = self.writer.encoding == "ros1"
                target = replace(conn, encoding=self.writer.encoding, msgdef="", msgdef_format="", digest="",
                                 qos=() if ros1 else (conn.qos or (latched_qos() if conn.ros1_latching else ())),
                                 callerid=conn.callerid if ros1 else None, latching=conn.latching if ros1 else None,
                                 metadata=(), schema_name="")
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
        fn = self._converters[conn.key]  # made by output(), before any record of the connection
        try:
            return bytes(fn(rec.data))
        except read_errors() as err:
            raise InputError(f"{self.reader.path}: {conn.topic}: cannot convert a {conn.msgtype} message from "
                             f"{conn.encoding} to {self.writer.encoding} encoding ({err})") from err

    def _converter(self, conn: LogConnection) -> Callable:
        """Bytes in ``conn``'s encoding to the writer's, by rosbags' converter: from the input's stored
        definition (the standard one where it stores none) to the writer's typestore, into which the input's
        types that the other ROS version lacks are registered."""
        from rosbags.convert.converter import generate_message_converter
        from rosbags.typesys import Stores, get_typestore

        where = f"{self.reader.path}: {conn.topic}"
        unusable = ""
        try:
            src = stored_typestore(conn)
        except Exception as err:  # noqa: BLE001 - an unparsable definition: the standard one must do
            src, unusable = None, first_line(err)
        if src is None:
            src = get_typestore(Stores.ROS1_NOETIC if conn.encoding == "ros1" else Stores.ROS2_HUMBLE)
            if conn.msgtype not in src.types:
                what = (f"the input's definition of {conn.msgtype} cannot be used ({unusable or 'it does not define it'})"
                        if conn.msgdef else f"the input stores no definition of {conn.msgtype}")
                keep = " or ".join(f for f, held in FORMAT_ENCODINGS.items() if conn.encoding in held)
                raise InputError(f"{where}: {what} and it is not a standard message type, so lio cannot convert it "
                                 f"from {conn.encoding} to {self.writer.encoding} encoding; write a format that "
                                 f"keeps {conn.encoding} instead (--format {keep})")
        dst = self.writer.typestore
        if conn.msgtype not in dst.types:  # a type the other version lacks: the input's definition, in its form
            try:
                dst.register({k: v for k, v in src.fielddefs.items() if k not in dst.types})
            except Exception as err:  # noqa: BLE001 - rosbags refuses a definition it cannot generate
                raise InputError(f"{where}: cannot define {conn.msgtype} for {self.writer.format} from the "
                                 f"input's definition ({first_line(err)})") from err
        try:
            with contextlib.redirect_stdout(io.StringIO()):  # rosbags notes each migrated type on stdout
                return generate_message_converter(src, dst, conn.msgtype, conn.msgtype, {},
                                                  src_is2=conn.encoding == "cdr", dst_is2=self.writer.encoding == "cdr")
        except Exception as err:  # noqa: BLE001 - definitions rosbags cannot map onto each other
            raise InputError(f"{where}: cannot convert {conn.msgtype} from {conn.encoding} to {self.writer.encoding} "
                             f"encoding ({first_line(err)})") from err
