"""Write logs: ROS 1 bag, ROS 2 bag folder (sqlite3 or mcap storage) or bare MCAP file.

The log is written to a temporary sibling and renamed into place on ``close()``; on error (``abort()`` or
an exception inside ``with``) nothing is left behind and an existing output is untouched.
"""

from __future__ import annotations

from pathlib import Path

from ..errors import InputError
from .files import check_writable, remove_path, replace_path, temp_sibling
from .messages import MessageFactory

WRITE_FORMATS = ("ros1", "ros2", "ros2-mcap", "mcap")
TF_MESSAGE_DEF = "geometry_msgs/TransformStamped[] transforms\n"


class LogWriter:
    """``add_topic(topic, msgtype)`` then ``write(topic, time_ns, msg)`` in any order of time."""

    def __init__(self, path: str | Path, fmt: str, force: bool = False) -> None:
        from rosbags.typesys import Stores, get_typestore

        if fmt not in WRITE_FORMATS:
            raise InputError(f"unknown output format '{fmt}' (choose from {', '.join(WRITE_FORMATS)})")
        self.path = Path(path)
        self.format = fmt
        check_writable(self.path, force)
        self.typestore = get_typestore(Stores.ROS1_NOETIC if fmt == "ros1" else Stores.ROS2_HUMBLE)
        if "tf2_msgs/msg/TFMessage" not in self.typestore.types:  # ROS 1 store lacks tf2_msgs
            from rosbags.typesys import get_types_from_msg

            self.typestore.register(get_types_from_msg(TF_MESSAGE_DEF, "tf2_msgs/msg/TFMessage"))
        self.make = MessageFactory(self.typestore)
        # rosbags names a ROS 2 bag's storage file after its folder, so a ROS 2 bag is written under its
        # final name inside a temporary sibling folder (not as a hidden temp name that would stick).
        self._tmpdir = temp_sibling(self.path) if fmt in ("ros2", "ros2-mcap") else None
        if self._tmpdir is not None:
            self._tmpdir.mkdir()
            self._tmp = self._tmpdir / self.path.name
        else:
            self._tmp = temp_sibling(self.path)
        self._topics: dict[str, tuple[str, object]] = {}
        self._seq: dict[str, int] = {}
        try:
            self._open()
        except Exception as err:
            self._discard()
            raise InputError(f"{self.path}: cannot create log ({err})") from err

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

            conn = self._w.add_connection(topic, msgtype, typestore=self.typestore)
        else:
            if msgtype not in self._schemas:
                msgdef, _ = self.typestore.generate_msgdef(msgtype, ros_version=2)
                self._schemas[msgtype] = self._w.register_schema(msgtype, "ros2msg", msgdef.encode())
            conn = self._w.register_channel(topic, "cdr", self._schemas[msgtype])
        self._topics[topic] = (msgtype, conn)
        self._seq[topic] = 0

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
        try:
            if self.format == "mcap":
                self._w.finish()
                self._file.close()
            else:
                self._w.close()
        except Exception as err:
            self.abort()
            raise InputError(f"{self.path}: cannot finish writing log ({err})") from err
        replace_path(self._tmp, self.path)
        if self._tmpdir is not None:
            remove_path(self._tmpdir)

    def abort(self) -> None:
        try:
            if self.format == "mcap":
                self._file.close()
            else:
                self._w.close()
        except Exception:  # noqa: BLE001 - the temp output is discarded anyway
            pass
        self._discard()

    def __enter__(self) -> "LogWriter":
        return self

    def __exit__(self, exc_type, exc, tb) -> None:
        if exc_type is None:
            self.close()
        else:
            self.abort()
