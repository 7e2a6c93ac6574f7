"""Shared fixtures: a factory that writes tiny logs in every format into ``tmp_path``.

Logs are written through ``LogWriter`` (rosbags' ROS 1 / ROS 2 writers, mcap's writer for bare MCAP);
``tests/io/test_logs.py`` also writes with rosbags' ``Writer`` directly to prove third-party logs read.
"""

from __future__ import annotations

import itertools
import os
import signal
import threading
from collections.abc import Callable
from pathlib import Path

import numpy as np
import pytest

# rich colours or narrows help and usage under these, read when typer is first imported (a CI's own settings)
for _name in ("GITHUB_ACTIONS", "FORCE_COLOR", "PY_COLORS", "TERMINAL_WIDTH"):
    os.environ.pop(_name, None)

from lio_cli.geometry import make_pose, so3_exp  # noqa: E402
from lio_cli.io.logs.writer import LogWriter  # noqa: E402

# Every format LogWriter writes, and the reader format it comes back as.
WRITE_FORMATS = ("ros1", "ros2", "ros2-mcap", "mcap")
READ_FORMAT = {"ros1": "ros1", "ros2": "ros2", "ros2-mcap": "ros2", "mcap": "mcap"}
SUFFIX = {"ros1": ".bag", "ros2": "", "ros2-mcap": "", "mcap": ".mcap"}

T0_NS = 1_700_000_000 * 10**9  # a realistic epoch, so absolute-time precision is exercised
SCAN_PERIOD_NS = 100_000_000
STEP_512_NS = 1_953_125  # 1/512 s: exact in float32 and float64 and a whole number of ns

PointCloud2 = "sensor_msgs/msg/PointCloud2"
LaserScan = "sensor_msgs/msg/LaserScan"
Imu = "sensor_msgs/msg/Imu"
Odometry = "nav_msgs/msg/Odometry"
TwistStamped = "geometry_msgs/msg/TwistStamped"
PoseStamped = "geometry_msgs/msg/PoseStamped"
TransformStamped = "geometry_msgs/msg/TransformStamped"
TFMessage = "tf2_msgs/msg/TFMessage"

# a driver's own message type, in no standard typestore (as ouster_ros/PacketMsg): ROS 1 definition
PACKET = "lio_test/msg/Packet"
PACKET_DEF = ("std_msgs/Header header\nuint8 KIND_IMU=1\nuint8 kind\nuint8[] buf\n" + "=" * 80 + "\n"
              "MSG: std_msgs/Header\nuint32 seq\ntime stamp\nstring frame_id\n")

T_BASE_IMU = make_pose(so3_exp(np.array([0.0, 0.0, np.pi / 2])), np.array([0.1, 0.0, 0.05]))
T_IMU_LIDAR = make_pose(so3_exp(np.array([0.02, -0.01, 0.3])), np.array([0.0, 0.2, 0.3]))


def structured(fields: list[tuple[str, str]], n: int, offsets: list[int] | None = None,
               itemsize: int | None = None) -> np.ndarray:
    """A zeroed structured array of ``n`` points; explicit offsets/itemsize give padded layouts."""
    names = [f for f, _ in fields]
    formats = [d for _, d in fields]
    if offsets is None:
        return np.zeros(n, dtype=np.dtype({"names": names, "formats": formats}))
    spec = {"names": names, "formats": formats, "offsets": offsets}
    if itemsize is not None:
        spec["itemsize"] = itemsize
    return np.zeros(n, dtype=np.dtype(spec))


def ring_xyz(n: int, radius_m: float = 5.0, clockwise: bool = False, z_m: float = 0.5) -> np.ndarray:
    """``n`` points on a circle starting at azimuth 0, in spin order."""
    az = 2 * np.pi * np.arange(n) / n
    if clockwise:
        az = -az
    return np.stack([radius_m * np.cos(az), radius_m * np.sin(az), np.full(n, z_m)], axis=1)


def velodyne_cloud(n: int = 52, header_at_end: bool = False) -> tuple[np.ndarray, np.ndarray]:
    """(structured array x,y,z,intensity,time(float32 s), expected offsets ns from the header)."""
    arr = structured([("x", "<f4"), ("y", "<f4"), ("z", "<f4"), ("intensity", "<f4"), ("time", "<f4")], n)
    xyz = ring_xyz(n)
    arr["x"], arr["y"], arr["z"] = xyz.T
    k = np.arange(n, dtype=np.int64)
    if header_at_end:
        k = k - (n - 1)
    arr["time"] = k / 512.0
    return arr, k * STEP_512_NS


def copy_log(src: Path, out: Path, fmt: str):
    """``src`` written as ``out`` in ``fmt`` by ``LogCopy`` (every connection; returns the ``LogCopy``, whose
    ``copied``/``converted`` count what it did)."""
    from lio_cli.io.logs.copy import LogCopy
    from lio_cli.io.logs.reader import open_log

    with open_log(src) as r, LogWriter(out, fmt) as w:
        copy = LogCopy(r, w)
        copy.mirror_all()
        for rec in r.records():
            copy.copy(rec)
    return copy


def packet_messages(n: int, t0_ns: int) -> list[tuple[int, bytes]]:
    """``n`` ROS 1 serialised ``PACKET`` messages, 0.1 s apart from ``t0_ns``: (record time, bytes)."""
    from rosbags.typesys import Stores, get_types_from_msg, get_typestore

    store = get_typestore(Stores.EMPTY)
    store.register(get_types_from_msg(PACKET_DEF, PACKET))
    T = store.types
    out = []
    for i in range(n):
        t = t0_ns + i * SCAN_PERIOD_NS
        header = T["std_msgs/msg/Header"](seq=i, stamp=T["builtin_interfaces/msg/Time"](sec=t // 10**9, nanosec=t % 10**9),
                                           frame_id="sensor")
        msg = T[PACKET](header=header, kind=1, buf=np.arange(i + 3, dtype=np.uint8))
        out.append((t, bytes(store.serialize_ros1(msg, PACKET))))
    return out


def ros1_mcap(bag: Path, out: Path, packets: int = 0) -> Path:
    """The ROS 1 bag ``bag`` as an MCAP file of mcap's ros1 profile, as ROS 1 bag converters write it:
    ``ros1msg`` schemas named ``pkg/Type``, ``ros1`` channels with caller id and latching metadata, no md5;
    plus ``packets`` messages of a driver's own type (``PACKET``) on /packets."""
    from mcap.writer import Writer
    from rosbags.rosbag1 import Reader

    with Reader(bag) as r, out.open("wb") as f:
        w = Writer(f)
        w.start(profile="ros1", library="test")
        schemas: dict[tuple, int] = {}
        channels = {}
        conns = [(c.id, c.topic, c.msgtype, c.msgdef.data, c.ext.callerid, c.ext.latching) for c in r.connections]
        if packets:
            conns.append((None, "/packets", PACKET, PACKET_DEF, "/driver", 0))
        for cid, topic, msgtype, msgdef, callerid, latching in conns:
            key = (msgtype, msgdef)
            if key not in schemas:
                schemas[key] = w.register_schema(msgtype.replace("/msg/", "/"), "ros1msg", msgdef.encode())
            meta = {"latching": str(int(latching or 0))} | ({"callerid": callerid} if callerid else {})
            channels[cid] = w.register_channel(topic, "ros1", schemas[key], meta)
        stored = [(channels[c.id], t, data) for c, t, data in r.messages()]
        stored += [(channels[None], t, data) for t, data in packet_messages(packets, r.start_time)]
        for seq, (channel, t, data) in enumerate(stored):
            w.add_message(channel, log_time=t, publish_time=t, sequence=seq, data=data)
        w.finish()
    return out


def anyreader_count(path: Path) -> int:
    """Messages rosbags' AnyReader reads and deserialises from ``path``."""
    from rosbags.highlevel import AnyReader

    with AnyReader([Path(path)]) as r:
        return sum(1 for c, _, raw in r.messages() if r.deserialize(raw, c.msgtype) is not None)


def decoded(path: Path, topic: str) -> list:
    """(record time, the message's field values as nested tuples) of ``topic``: what a conversion between ROS 1
    and ROS 2 keeps (a ROS 1 header's seq is left out: ROS 2 has none)."""
    from lio_cli.io.logs.reader import open_log

    def plain(value):
        if hasattr(value, "__dataclass_fields__"):
            return tuple((name, plain(getattr(value, name))) for name in value.__dataclass_fields__
                         if name != "__msgtype__" and not (name == "seq" and value.__msgtype__ == "std_msgs/msg/Header"))
        if isinstance(value, np.ndarray):
            return value.tolist()
        return [plain(v) for v in value] if isinstance(value, list) else value

    with open_log(path) as r:
        return [(t, plain(m)) for _, _, t, m in r.messages([topic])]


class LogFactory:
    """Write tiny logs in ``root``: ``write(fmt, build)`` with ``build(writer)``, or ``sensor_log(fmt)``."""

    # helpers and constants, reachable from any test through the fixture (no conftest imports)
    structured = staticmethod(structured)
    ring_xyz = staticmethod(ring_xyz)
    velodyne_cloud = staticmethod(velodyne_cloud)
    T0_NS, SCAN_PERIOD_NS, STEP_512_NS = T0_NS, SCAN_PERIOD_NS, STEP_512_NS
    T_BASE_IMU, T_IMU_LIDAR = T_BASE_IMU, T_IMU_LIDAR
    READ_FORMAT = READ_FORMAT
    PACKET, PACKET_DEF = PACKET, PACKET_DEF
    copy_log = staticmethod(copy_log)
    ros1_mcap = staticmethod(ros1_mcap)
    packet_messages = staticmethod(packet_messages)
    anyreader_count = staticmethod(anyreader_count)
    decoded = staticmethod(decoded)

    def __init__(self, root: Path) -> None:
        self.root = root
        self._n = itertools.count()

    def path(self, fmt: str, name: str | None = None) -> Path:
        return self.root / f"{name or f'log{next(self._n)}'}{SUFFIX[fmt]}"

    def write(self, fmt: str, build: Callable[[LogWriter], None], name: str | None = None) -> Path:
        path = self.path(fmt, name)
        with LogWriter(path, fmt) as w:
            build(w)
        return path

    def sensor_log(
        self,
        fmt: str,
        *,
        duration_s: float = 0.5,
        lidar_hz: int = 10,
        imu_hz: int = 100,
        wheel_hz: int = 20,
        gt_hz: int = 10,
        cloud: Callable[[int], np.ndarray] | None = None,
        lidar_delay_ns: int = 5_000_000,
        name: str | None = None,
        extra: Callable[[LogWriter], None] | None = None,
    ) -> Path:
        """A small robot log: /points (velodyne clouds), /imu, /odom, /ground_truth and /tf_static.

        Messages are recorded after their header stamps (clouds ``lidar_delay_ns`` late), as drivers do.
        """

        def build(w: LogWriter) -> None:
            m = w.make
            w.add_topic("/tf_static", TFMessage, latching=True)
            w.add_topic("/points", PointCloud2)
            w.add_topic("/imu", Imu)
            w.add_topic("/odom", Odometry)
            w.add_topic("/ground_truth", PoseStamped)
            w.write("/tf_static", T0_NS, m.tf_message([
                m.transform_stamped(T0_NS, "base_link", "imu_link", T_BASE_IMU),
                m.transform_stamped(T0_NS, "imu_link", "velodyne", T_IMU_LIDAR),
            ]))
            end = T0_NS + int(duration_s * 1e9)
            for t in range(T0_NS, end, 10**9 // lidar_hz):
                arr = cloud(t) if cloud is not None else velodyne_cloud()[0]
                w.write("/points", t + lidar_delay_ns, m.pointcloud2(t, "velodyne", arr))
            for i, t in enumerate(range(T0_NS, end, 10**9 // imu_hz)):
                w.write("/imu", t + 1000, m.imu(t, "imu_link", [0.01 * i, 0.0, 0.1], [0.0, 0.0, 9.81]))
            for t in range(T0_NS, end, 10**9 // wheel_hz):
                x = (t - T0_NS) * 1e-9
                w.write("/odom", t + 2000, m.odometry(t, "odom", "base_link", make_pose(t=[x, 0, 0]),
                                                     [1.0, 0, 0], [0, 0, 0.1]))
            for t in range(T0_NS, end, 10**9 // gt_hz):
                x = (t - T0_NS) * 1e-9
                w.write("/ground_truth", t + 3000, m.pose_stamped(t, "world", make_pose(t=[x, 0, 0])))
            if extra is not None:
                extra(w)

        return self.write(fmt, build, name)


@pytest.fixture(autouse=True)
def _foreground_signals():
    """Every test starts with Ctrl-C as a terminal's foreground job has it: a test that left SIGINT ignored or
    blocked in this worker would pass that on to the processes later tests start, which then never see it."""
    signal.pthread_sigmask(signal.SIG_UNBLOCK, {signal.SIGINT, signal.SIGTERM})
    if threading.current_thread() is threading.main_thread():
        signal.signal(signal.SIGINT, signal.default_int_handler)
    yield


@pytest.fixture
def logs(tmp_path: Path) -> LogFactory:
    return LogFactory(tmp_path)


@pytest.fixture(scope="session")
def log_tools() -> type[LogFactory]:
    """The factory's helpers and constants (``copy_log``, ``ros1_mcap``...) for fixtures wider than a test."""
    return LogFactory


@pytest.fixture(params=WRITE_FORMATS)
def write_format(request) -> str:
    """Each format LogWriter writes: ros1, ros2 (sqlite3), ros2-mcap, mcap."""
    return request.param


@pytest.fixture(scope="session")
def real_logs() -> Path:
    """``../shared/real_logs`` beside the repository (the workplace's copy for a worktree elsewhere); a test
    that takes it is skipped, saying why, where a clone has no such folder."""
    beside = Path(__file__).resolve().parents[1].parent / "shared" / "real_logs"
    path = beside if beside.is_dir() else Path("/work/shared/real_logs")
    if not path.is_dir():
        pytest.skip(f"real recordings absent: {beside} does not exist (they live in the workplace's "
                    "shared/real_logs and are never copied into the repository)")
    return path
