"""Write logs: ROS 1 bag, ROS 2 bag folder (sqlite3 or mcap storage) or bare MCAP file.

The log is written to a temporary sibling and renamed into place on ``close()``; on error (``abort()`` or
an exception inside ``with``) nothing is left behind and an existing output is untouched.

Two ways to add a connection: ``add_topic`` (a standard type, defined by the writer's typestore) and
``add_mirror`` (a copy of another log's connection: its definition, hash and the metadata the output format
holds), whose messages are then written as stored with ``write_record``.
"""

from __future__ import annotations

import contextlib

from functools import cached_property
from collections.abc import Callable
from pathlib import Path

from ...errors import InputError
from ..files.atomic import check_writable, no_space_error, remove_path, replace_path, temp_sibling
from ..messages.encode import MessageFactory
from ..messages.msgdefs import output_definition
from .base import LogConnection

WRITE_FORMATS = ("ros1", "ros2", "ros2-mcap", "mcap")
TF_MESSAGE_DEF = "geometry_msgs/TransformStamped[] transforms\n"
# the message encodings each output format holds: bare MCAP is CDR (the ros2 profile; AnyReader refuses ros1's)
FORMAT_ENCODINGS = {"ros1": ("ros1",), "ros2": ("cdr",), "ros2-mcap": ("cdr",), "mcap": ("cdr",)}
# the formats written as one file, and their suffixes (readers go by them; a ROS 2 bag is a folder)
FILE_SUFFIXES = {"ros1": ".bag", "mcap": ".mcap"}
SUFFIX_FORMATS = {suffix: fmt for fmt, suffix in FILE_SUFFIXES.items()}


def latched_qos() -> tuple:
    """ROS 2's form of a ROS 1 latched topic (/tf_static): transient local, reliable, the last message kept, so
    a player offers it to late subscribers as ROS 1 did (an empty profile plays it volatile)."""
    from rosbags.interfaces import Qos, QosDurability, QosHistory, QosLiveliness, QosReliability, QosTime

    never = QosTime(0, 0)
    return (Qos(QosHistory.KEEP_LAST, 1, QosReliability.RELIABLE, QosDurability.TRANSIENT_LOCAL, never, never,
                QosLiveliness.SYSTEM_DEFAULT, never, False),)


class LogWriter:
    """``add_topic(topic, msgtype)`` then ``write(topic, time_ns, msg)`` in any order of time."""

    def __init__(self, path: str | Path, fmt: str, force: bool = False,
                 on_temp: Callable[[Path], None] | None = None) -> None:
        """``on_temp``: told the temporary path (file or ROS 2 folder) before it is created."""
        if fmt not in WRITE_FORMATS:
            raise InputError(f"unknown output format '{fmt}' (choose from {', '.join(WRITE_FORMATS)})")
        self.path = Path(path)
        self.format = fmt
        check_writable(self.path, force)
        # rosbags names a ROS 2 bag's storage file after its folder: its final name, in a temporary sibling folder
        self._tmpdir = temp_sibling(self.path) if fmt in ("ros2", "ros2-mcap") else None
        self._tmp = self._tmpdir / self.path.name if self._tmpdir is not None else temp_sibling(self.path)
        if on_temp is not None:
            on_temp(self.temp_path)
        if self._tmpdir is not None:
            self._tmpdir.mkdir()
        self._topics: dict[str, tuple[str, object]] = {}
        self._seq: dict[str, int] = {}
        self._mirrors: list[list] = []  # per key: [output connection, encoding, next sequence number]
        self._mirror_keys: dict[tuple, int] = {}  # identical connections share one output connection
        try:
            self._open()
        except Exception as err:
            self._discard()
            if (full := no_space_error(err, self.path)) is not None:
                raise full from err
            raise InputError(f"{self.path}: cannot create log ({err})") from err
        except BaseException:  # interrupted while creating it
            self._discard()
            raise

    @cached_property
    def typestore(self):
        """The standard types of the output's ROS version (built on first use: a copy of stored records never
        needs them)."""
        from rosbags.typesys import Stores, get_types_from_msg, get_typestore

        store = get_typestore(Stores.ROS1_NOETIC if self.format == "ros1" else Stores.ROS2_HUMBLE)
        if "tf2_msgs/msg/TFMessage" not in store.types:  # ROS 1 store lacks tf2_msgs
            store.register(get_types_from_msg(TF_MESSAGE_DEF, "tf2_msgs/msg/TFMessage"))
        return store

    @cached_property
    def make(self) -> MessageFactory:
        return MessageFactory(self.typestore)

    @property
    def temp_path(self) -> Path:
        """Where the log is written until ``close`` renames it (a folder for a ROS 2 bag)."""
        return self._tmpdir if self._tmpdir is not None else self._tmp

    def _discard(self) -> None:
        remove_path(self._tmpdir if self._tmpdir is not None else self._tmp)

    def _open(self) -> None:
        if self.format == "ros1":
            from rosbags.rosbag1 import Writer

            self._w = Writer(self._tmp)
            self._w.open()
        elif self.format in ("ros2", "ros2-mcap"):
            from rosbags.rosbag2 import StoragePlugin, Writer

            plugin = StoragePlugin.MCAP if self.format == "ros2-mcap" else StoragePlugin.SQLITE3
            self._w = Writer(self._tmp, version=8, storage_plugin=plugin)
            self._w.open()
        else:
            from mcap.writer import Writer

            self._file = self._tmp.open("wb")
            self._w = Writer(self._file)
            self._w.start(profile="ros2", library="lio")
            self._schemas: dict[str, int] = {}

    def add_topic(self, topic: str, msgtype: str, latching: bool = False) -> None:
        if topic in self._topics:
            return
        if self.format == "ros1":
            conn = self._w.add_connection(topic, msgtype, typestore=self.typestore, latching=int(latching))
        elif self.format in ("ros2", "ros2-mcap"):
            conn = self._w.add_connection(topic, msgtype, typestore=self.typestore,
                                          offered_qos_profiles=latched_qos() if latching else ())
        else:
            if msgtype not in self._schemas:
                msgdef, _ = self.typestore.generate_msgdef(msgtype, ros_version=2)
                self._schemas[msgtype] = self._w.register_schema(msgtype, "ros2msg", msgdef.encode())
            meta = {}
            if latching:
                from rosbags.rosbag2.metadata import dump_qos_v8

                meta["offered_qos_profiles"] = dump_qos_v8(list(latched_qos()))
            conn = self._w.register_channel(topic, "cdr", self._schemas[msgtype], meta)
        self._topics[topic] = (msgtype, conn)
        self._seq[topic] = 0

    @property
    def encoding(self) -> str:
        """The encoding of messages added with ``add_topic``: ``ros1`` for a ROS 1 bag, ``cdr`` otherwise."""
        return "ros1" if self.format == "ros1" else "cdr"

    def add_mirror(self, conn: LogConnection, topic: str | None = None) -> int:
        """A connection like ``conn`` (renamed to ``topic`` when given), for its messages as stored; returns the
        key ``write_record`` takes. ``conn.encoding`` must be one this format holds (``FORMAT_ENCODINGS``).

        Kept: type, definition and hash (computed from the definition where ``conn`` has none: MCAP); ROS 1
        caller id and latching (an MCAP channel's metadata names them); ROS 2 QoS profiles; MCAP schema and
        channel metadata (ROS 2 QoS travel there as the ros2 profile names them).
        """
        if conn.encoding not in FORMAT_ENCODINGS[self.format]:
            raise InputError(f"{self.path}: a {self.format} log cannot hold {conn.encoding}-encoded messages "
                             f"({conn.topic}); convert them first")
        topic = topic or conn.topic
        sig = (topic, conn.msgtype, conn.encoding, conn.msgdef, conn.digest, conn.callerid, conn.latching,
               repr(conn.qos), conn.metadata)
        if sig in self._mirror_keys:
            return self._mirror_keys[sig]
        try:
            out = self._mirror_connection(conn, topic)
        except InputError:
            raise
        except Exception as err:  # rosbags/mcap refuse a definition they cannot use
            raise InputError(f"{self.path}: cannot copy the connection of {conn.topic} ({conn.msgtype}): {err}") from err
        self._mirrors.append([out, conn.encoding, 0])
        key = self._mirror_keys[sig] = len(self._mirrors) - 1
        return key

    def _definition(self, conn: LogConnection, topic: str) -> tuple[str, str]:
        return output_definition(conn, self.typestore, 1 if self.format == "ros1" else 2, f"{self.path}: {topic}")

    def _mirror_connection(self, conn: LogConnection, topic: str):
        meta = dict(conn.metadata)
        if self.format == "ros1":
            msgdef, digest = self._definition(conn, topic)
            return self._w.add_connection(topic, conn.msgtype, msgdef=msgdef, md5sum=digest,
                                          callerid=conn.ros1_callerid, latching=conn.ros1_latching)
        if self.format in ("ros2", "ros2-mcap"):
            msgdef, digest = self._definition(conn, topic)
            qos = list(conn.qos)
            if not qos and meta.get("offered_qos_profiles"):
                from rosbags.rosbag2.metadata import parse_qos

                qos = parse_qos(meta["offered_qos_profiles"])
            return self._w.add_connection(topic, conn.msgtype, msgdef=msgdef, rihs01=digest,
                                          offered_qos_profiles=qos)
        msgdef, fmt = conn.msgdef, conn.msgdef_format
        if not msgdef:
            msgdef, _ = self._definition(conn, topic)
            fmt = "ros2msg"
        name = conn.schema_name or conn.msgtype
        schema_key = (name, fmt, msgdef)
        if schema_key not in self._schemas:
            self._schemas[schema_key] = self._w.register_schema(name, fmt, msgdef.encode())
        if conn.qos and "offered_qos_profiles" not in meta:
            from rosbags.rosbag2.metadata import dump_qos_v8

            meta["offered_qos_profiles"] = dump_qos_v8(list(conn.qos))
        return self._w.register_channel(topic, conn.encoding, self._schemas[schema_key], metadata=meta)

    def write_record(self, key: int, time_ns: int, data: bytes, publish_time_ns: int | None = None,
                     sequence: int | None = None) -> None:
        """Write stored bytes on a connection from ``add_mirror`` at record time ``time_ns`` (integer ns; MCAP
        also keeps the publish time and sequence number when given)."""
        mirror = self._mirrors[key]
        if self.format != "mcap":  # the hot path of a copy: straight to rosbags
            self._w.write(mirror[0], time_ns, data)
            return
        seq = mirror[2] if sequence is None else sequence
        self._w.add_message(mirror[0], log_time=time_ns, data=data,
                            publish_time=time_ns if publish_time_ns is None else publish_time_ns, sequence=seq)
        mirror[2] += 1

    def serialize(self, msg, msgtype: str) -> bytes:
        if self.format == "ros1":
            return bytes(self.typestore.serialize_ros1(msg, msgtype))
        return bytes(self.typestore.serialize_cdr(msg, msgtype))

    def write(self, topic: str, time_ns: int, msg) -> None:
        msgtype, _ = self._topics[topic]
        self.write_raw(topic, time_ns, self.serialize(msg, msgtype))

    def write_raw(self, topic: str, time_ns: int, data: bytes) -> None:
        """Write already-serialised bytes (ROS 1 serialisation for ros1, CDR otherwise)."""
        _, conn = self._topics[topic]
        if self.format == "mcap":
            self._w.add_message(conn, log_time=int(time_ns), data=data, publish_time=int(time_ns),
                                sequence=self._seq[topic])
        else:
            self._w.write(conn, int(time_ns), data)
        self._seq[topic] += 1

    def close(self) -> None:
        """``finish`` then ``commit``."""
        self.finish()
        self.commit()

    def finish(self) -> None:
        """Write the log's end (indexes, summaries) into its temporary; nothing is in place yet."""
        try:
            if self.format == "mcap":
                self._w.finish()
                self._file.close()
            else:
                self._w.close()
        except Exception as err:
            self.abort()
            if (full := no_space_error(err, self.path)) is not None:
                raise full from err
            raise InputError(f"{self.path}: cannot finish writing log ({err})") from err
        except BaseException:
            self.abort()
            raise

    def commit(self) -> None:
        """Rename the finished log into place."""
        try:
            replace_path(self._tmp, self.path)
        except BaseException:
            self._discard()
            raise
        if self._tmpdir is not None:
            remove_path(self._tmpdir)

    def abort(self) -> None:
        try:
            if self.format == "mcap":
                self._file.close()
            else:
                self._w.close()
        except Exception:  # noqa: BLE001 - the temp output is discarded anyway
            # a close that failed (a full device) may leave the file open: its space would stay taken while
            # the writer lives
            bio = getattr(self._w, "bio", None)
            if bio is not None:
                with contextlib.suppress(Exception):
                    bio.close()
        finally:  # an interrupt while closing too
            self._discard()

    def __enter__(self) -> "LogWriter":
        return self

    def __exit__(self, exc_type, exc, tb) -> None:
        if exc_type is None:
            self.close()
        else:
            self.abort()
