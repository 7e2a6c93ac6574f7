"""Shared fixtures: a factory that writes tiny logs in every format into ``tmp_path``.

Logs are written through ``LogWriter`` (rosbags' ROS 1 / ROS 2 writers, mcap's writer for bare MCAP);
``tests/io/test_logs.py`` also writes with rosbags' ``Writer`` directly to prove third-party logs read.
"""

from __future__ import annotations

import itertools
from collections.abc import Callable
from pathlib import Path

import numpy as np
import pytest

from lio_cli.geometry import make_pose, so3_exp
from lio_cli.io.writer import LogWriter

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


class LogFactory:
    """Write tiny logs in ``root``: ``write(fmt, build)`` with ``build(writer)``, or ``sensor_log(fmt)``."""

    # helpers and constants, reachable from any test through the fixture (no conftest imports)
    structured = staticmethod(structured)
    ring_xyz = staticmethod(ring_xyz)
    velodyne_cloud = staticmethod(velodyne_cloud)
    T0_NS, SCAN_PERIOD_NS, STEP_512_NS = T0_NS, SCAN_PERIOD_NS, STEP_512_NS
    T_BASE_IMU, T_IMU_LIDAR = T_BASE_IMU, T_IMU_LIDAR
    READ_FORMAT = READ_FORMAT

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


@pytest.fixture
def logs(tmp_path: Path) -> LogFactory:
    return LogFactory(tmp_path)


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
