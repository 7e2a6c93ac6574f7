"""Hand-checkable logs for ``lio fuse``: a unicycle at constant speed and yaw rate, measured exactly.

The base moves from the first sample with speed ``v`` and yaw rate ``w``: position
``(v/w sin wt, v/w (1 - cos wt), 0)`` (``(v t, 0, 0)`` for w = 0), heading ``w t``. The IMU (mounted by
``T_base_imu``, lever arm included) reads the base's rate and specific force ``(0, v w, 9.81)`` moved to its own
origin and axes; the wheels report ``(v, 0, 0)`` and ``w`` in the base (or, ``twist_frame="parent"``, the linear
twist in the odometry frame as some drivers do); GPS fixes are the true positions around a georeference.
Every message is recorded 1 ms after its stamp unless ``edit`` changes it: ``edit(topic, list of (record_ns,
message))`` may drop, repeat, delay or spoil messages before they are written.
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np
import pytest

from lio_cli.geodesy import EnuFrame
from lio_cli.geometry import make_pose, rot_to_quat_xyzw, so3_exp

T0_NS = 1_700_000_000 * 10**9
ORIGIN = EnuFrame(47.37, 8.54, 408.0)
T_BASE_IMU = make_pose(so3_exp(np.array([0.0, 0.0, np.pi / 2])), np.array([0.1, 0.0, 0.05]))
G = 9.81


def unicycle(t_s: np.ndarray, v: float, w: float) -> tuple[np.ndarray, np.ndarray]:
    """(positions (N,3), yaw (N,)) at ``t_s``."""
    t = np.asarray(t_s, float)
    yaw = w * t
    if w == 0.0:
        p = np.column_stack([v * t, np.zeros_like(t), np.zeros_like(t)])
    else:
        p = np.column_stack([v / w * np.sin(yaw), v / w * (1 - np.cos(yaw)), np.zeros_like(t)])
    return p, yaw


class FuseLogs:
    """Write unicycle logs (see the module docstring) through the shared ``logs`` factory."""

    T0_NS, ORIGIN, T_BASE_IMU = T0_NS, ORIGIN, T_BASE_IMU
    unicycle = staticmethod(unicycle)

    def __init__(self, factory) -> None:
        self.factory = factory

    def write(self, fmt: str = "ros1", *, duration_s: float = 5.0, v: float = 1.0, w: float = 0.0,
              imu_hz: int = 100, wheel_hz: int = 20, gps_hz: float = 0.0, imu: bool = True,
              wheel: str | None = "odometry", imu_frame: str = "imu", tf: bool = True,
              imu_orientation: bool = False, twist_frame: str = "child", twist_only: bool = False,
              wheel_cov: float = 0.0, gps_status: int = 0, imu_stamp_shift_ns: int = 0,
              edit: Callable[[str, list], list] | None = None, name: str | None = None):
        R_bi, r = T_BASE_IMU[:3, :3], T_BASE_IMU[:3, 3]
        end = T0_NS + int(round(duration_s * 1e9))

        def build(wr) -> None:
            m = wr.make
            streams: dict[str, list] = {}
            if tf:
                wr.add_topic("/tf_static", "tf2_msgs/msg/TFMessage", latching=True)
                streams["/tf_static"] = [(T0_NS, m.tf_message([m.transform_stamped(T0_NS, "base_link", "imu",
                                                                                     T_BASE_IMU)]))]
            if imu:
                wr.add_topic("/imu", "sensor_msgs/msg/Imu")
                st = np.arange(T0_NS, end + 1, 10**9 // imu_hz)
                _, yaw = unicycle((st - T0_NS) * 1e-9, v, w)
                om = np.array([0.0, 0.0, w])
                f_imu = R_bi.T @ (np.array([0.0, v * w, G]) + np.cross(om, np.cross(om, r)))
                msgs = []
                for t, y in zip(st, yaw):
                    msg = m.imu(int(t) + imu_stamp_shift_ns, imu_frame, R_bi.T @ om, f_imu)
                    if imu_orientation:  # R_world_imu = Rz(yaw) R_base_imu
                        msg.orientation = m.quaternion(rot_to_quat_xyzw(so3_exp(np.array([0, 0, y])) @ R_bi))
                        msg.orientation_covariance = np.diag([1e-4] * 3).reshape(9)
                    msgs.append((int(t) + 10**6, msg))
                streams["/imu"] = msgs
            if wheel is not None:
                msgtype = "nav_msgs/msg/Odometry" if wheel == "odometry" else "geometry_msgs/msg/TwistStamped"
                wr.add_topic("/wheel/odom", msgtype)
                st = np.arange(T0_NS, end + 1, 10**9 // wheel_hz)
                p, yaw = unicycle((st - T0_NS) * 1e-9, v, w)
                msgs = []
                for t, pk, y in zip(st, p, yaw):
                    lin = np.array([v, 0.0, 0.0])
                    if twist_frame == "parent":
                        lin = so3_exp(np.array([0, 0, y])) @ lin
                    if wheel == "odometry":
                        T = make_pose(so3_exp(np.array([0, 0, y])), pk)
                        msg = m.odometry(int(t), "odom", "base_link", T, lin, [0.0, 0.0, w])
                        if twist_only:
                            msg.pose.pose.orientation = m.quaternion((0.0, 0.0, 0.0, 0.0))
                        msg.twist.covariance = np.diag([wheel_cov] * 6).reshape(36)
                    else:
                        msg = m.twist_stamped(int(t), "base_link", lin, [0.0, 0.0, w])
                    msgs.append((int(t) + 10**6, msg))
                streams["/wheel/odom"] = msgs
            if gps_hz:
                wr.add_topic("/gps/fix", "sensor_msgs/msg/NavSatFix")
                st = np.arange(T0_NS, end + 1, int(10**9 / gps_hz))
                p, _ = unicycle((st - T0_NS) * 1e-9, v, w)
                lat, lon, alt = ORIGIN.to_geodetic(p)
                streams["/gps/fix"] = [(int(t) + 10**6, m.navsatfix(int(t), "gps", la, lo, al, status=gps_status,
                                                                     covariance_m2=np.diag([0.01, 0.01, 0.04]),
                                                                     covariance_type=2))
                                       for t, la, lo, al in zip(st, lat, lon, alt)]
            for topic, msgs in streams.items():
                for rec, msg in (edit(topic, msgs) if edit is not None else msgs):
                    wr.write(topic, rec, msg)

        return self.factory.write(fmt, build, name)


@pytest.fixture
def fuse_logs(logs) -> FuseLogs:
    return FuseLogs(logs)


def _rewrite_clouds(src, dst, edit):
    """A copy of a ROS 1 log with each /points cloud (structured array) passed through ``edit(k, arr)``."""
    from lio_cli.io.messages.pointcloud import cloud_dtype, stamp_to_ns
    from lio_cli.io.logs.reader import open_log
    from lio_cli.io.logs.writer import LogWriter

    with open_log(src) as r, LogWriter(dst, "ros1") as w:
        for topic, info in r.topics.items():
            w.add_topic(topic, info.msgtype, latching=topic == "/tf_static")
        k = 0
        for topic, _, t, msg in r.messages():
            if topic == "/points":
                arr = np.frombuffer(np.asarray(msg.data).tobytes(), dtype=cloud_dtype(msg)).copy()
                msg = w.make.pointcloud2(stamp_to_ns(msg.header.stamp), msg.header.frame_id, edit(k, arr))
                k += 1
            w.write(topic, t, msg)
    return dst


@pytest.fixture
def rewrite_clouds():
    """``rewrite_clouds(src, dst, edit)``: a copy of a ROS 1 log with each /points cloud passed through
    ``edit(k, structured array)``."""
    return _rewrite_clouds


def _without_messages(src, dst, topic: str, t0_ns: int, t1_ns: int):
    """A ROS 1 copy of ``src`` without the ``topic`` messages stamped in [t0, t1)."""
    from lio_cli.io.logs.reader import open_log
    from lio_cli.io.logs.writer import LogWriter

    with open_log(src) as reader, LogWriter(dst, "ros1") as w:
        for name, info in reader.topics.items():
            w.add_topic(name, info.msgtype, latching=name == "/tf_static")
        for name, _, t_ns, msg in reader.messages():
            if name == topic:
                stamp = msg.header.stamp.sec * 10**9 + msg.header.stamp.nanosec
                if t0_ns <= stamp < t1_ns:
                    continue
            w.write(name, t_ns, msg)
    return dst


@pytest.fixture
def without_messages():
    """``without_messages(src, dst, topic, t0_ns, t1_ns)``: a gap in one topic of a ROS 1 log."""
    return _without_messages


def _rewrite_messages(src, dst, topic: str, edit):
    """A ROS 1 copy of ``src`` with each ``topic`` message passed through ``edit(stamp_ns, msg)`` (returns the
    message to write, or None to leave it out)."""
    from lio_cli.io.logs.reader import open_log
    from lio_cli.io.logs.writer import LogWriter

    with open_log(src) as reader, LogWriter(dst, "ros1") as w:
        for name, info in reader.topics.items():
            w.add_topic(name, info.msgtype, latching=name == "/tf_static")
        for name, _, t_ns, msg in reader.messages():
            if name == topic:
                msg = edit(msg.header.stamp.sec * 10**9 + msg.header.stamp.nanosec, msg)
                if msg is None:  # left out
                    continue
            w.write(name, t_ns, msg)
    return dst


@pytest.fixture(scope="session")
def rewrite_messages():
    """``rewrite_messages(src, dst, topic, edit)``: a ROS 1 copy of a log with each ``topic`` message passed through
    ``edit(stamp_ns, msg)``."""
    return _rewrite_messages
