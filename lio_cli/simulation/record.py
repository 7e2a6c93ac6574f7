"""Write a simulated run's sensor streams into a log, in time order, as the drivers would have recorded them.

Scans are ray-cast one at a time and recorded at the end of their sweep; the small streams (IMU, wheel
odometry, ground truth, GPS) are merged in between, each recorded at its header stamp.
"""

from __future__ import annotations

import heapq
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ..io.logs.writer import LogWriter
from .gps import COVARIANCE_TYPE_UNKNOWN, STATUS_FIX, GpsFixes
from .motion import MotionState
from .options import SimulationOptions
from .scenarios import Scenario
from .sensors import NS, ImuData, LaserSpec, LidarSpec, Scan, WheelOdometry, laser_scan, spin_scan

TOPIC_POINTS, TOPIC_SCAN, TOPIC_IMU = "/points", "/scan", "/imu"
TOPIC_WHEEL, TOPIC_TF_STATIC, TOPIC_GPS = "/wheel/odom", "/tf_static", "/gps/fix"
GT_MSGTYPES = {"pose": "geometry_msgs/msg/PoseStamped", "odometry": "nav_msgs/msg/Odometry"}


@dataclass
class Streams:
    """What a run's sensors measured, ready to be written (scans are cast while writing)."""

    imu: ImuData
    gt_ns: np.ndarray
    gt_state: MotionState
    wheel: WheelOdometry | None
    gps: GpsFixes | None


def gt_type_of(sc: Scenario, opts: SimulationOptions) -> str:
    """pose, odometry or none: the option, else the scenario's (the static scenario has none)."""
    if opts.gt_type is not None:
        return opts.gt_type
    return "none" if sc.lidar is None else "pose"


def static_transforms(mk, stamp_ns: int, sc: Scenario, gps: bool) -> object:
    """The /tf_static message: base -> imu, base -> lidar (when there is one), base -> gps (when on)."""
    transforms = [mk.transform_stamped(stamp_ns, "base", "imu", sc.T_base_imu)]
    if sc.T_base_lidar is not None:
        transforms.append(mk.transform_stamped(stamp_ns, "base", "lidar", sc.T_base_lidar))
    if gps:
        T_base_gps = np.eye(4)
        T_base_gps[:3, 3] = sc.gps_antenna_m
        transforms.append(mk.transform_stamped(stamp_ns, "base", "gps", T_base_gps))
    return mk.tf_message(transforms)


def gt_message(mk, gt_type: str, twist: bool, t_ns: int, st: MotionState, i: int, T: np.ndarray):
    """Ground truth of base in world at sample ``i``: PoseStamped, or Odometry with a zero or true twist
    (REP 105: the twist in the child frame, base)."""
    if gt_type == "pose":
        return mk.pose_stamped(t_ns, "world", T)
    if twist:
        lin, ang = st.R_world_base[i].T @ st.velocity_mps[i], st.omega_base_radps[i]
    else:
        lin = ang = (0.0, 0.0, 0.0)
    return mk.odometry(t_ns, "world", "base", T, lin, ang)


def gps_message(mk, gps: GpsFixes, i: int):
    t = int(gps.stamps_ns[i])
    if gps.status[i] == STATUS_FIX:
        return mk.navsatfix(t, "gps", gps.lat_deg[i], gps.lon_deg[i], gps.alt_m[i], status=STATUS_FIX,
                            covariance_m2=np.diag(gps.covariance_enu_m2), covariance_type=gps.covariance_type)
    return mk.navsatfix(t, "gps", np.nan, np.nan, np.nan, status=int(gps.status[i]), covariance_m2=np.zeros(9),
                        covariance_type=COVARIANCE_TYPE_UNKNOWN)


def cloud_array(scan: Scan, convention: str, header_ns: int) -> np.ndarray:
    """The PointCloud2 point layout of each convention; relative times are offsets from ``header_ns``."""
    n = len(scan.points)
    rel_ns = scan.stamps_ns - header_ns
    if convention == "velodyne":
        dt = np.dtype([("x", "<f4"), ("y", "<f4"), ("z", "<f4"), ("intensity", "<f4"), ("ring", "<u2"), ("time", "<f4")])
    elif convention == "ouster":
        dt = np.dtype([("x", "<f4"), ("y", "<f4"), ("z", "<f4"), ("intensity", "<f4"), ("t", "<u4"),
                       ("reflectivity", "<u2"), ("ring", "<u2")])
    elif convention == "livox":
        dt = np.dtype([("x", "<f4"), ("y", "<f4"), ("z", "<f4"), ("intensity", "<f4"), ("tag", "u1"), ("line", "u1"),
                       ("offset_time", "<u4")])
    else:  # hesai
        dt = np.dtype([("x", "<f4"), ("y", "<f4"), ("z", "<f4"), ("intensity", "<f4"), ("timestamp", "<f8"), ("ring", "<u2")])
    arr = np.zeros(n, dtype=dt)
    arr["x"], arr["y"], arr["z"] = scan.points[:, 0], scan.points[:, 1], scan.points[:, 2]
    arr["intensity"] = scan.intensity
    if convention == "velodyne":
        arr["ring"], arr["time"] = scan.ring, rel_ns * 1e-9
    elif convention == "ouster":
        arr["t"], arr["ring"], arr["reflectivity"] = rel_ns, scan.ring, scan.intensity.astype(np.uint16)
    elif convention == "livox":
        arr["line"], arr["offset_time"] = scan.ring.astype(np.uint8), rel_ns
    else:
        arr["ring"] = scan.ring
        arr["timestamp"] = scan.stamps_ns // NS + (scan.stamps_ns % NS) * 1e-9
    return arr


def write_sensor_log(out: Path, fmt: str, force: bool, sc: Scenario, opts: SimulationOptions, data: Streams,
                     start_ns: int, end_ns: int, rng_lidar: np.random.Generator | None,
                     progress: Callable[[float], None] | None) -> tuple[dict[str, str], dict[str, int]]:
    """Write the log of a LiDAR scenario; returns (msgtype by topic, message count by topic)."""
    period = sc.lidar.period_ns
    n_scans = (end_ns - start_ns) // period
    spinning = isinstance(sc.lidar, LidarSpec)
    lidar_topic = TOPIC_POINTS if spinning else TOPIC_SCAN
    gt_type = gt_type_of(sc, opts)
    imu, wheel, gps = data.imu, data.wheel, data.gps
    gt_poses = data.gt_state.poses
    counts: dict[str, int] = {}
    with LogWriter(out, fmt, force=force) as wr:
        mk = wr.make
        types: dict[str, str] = {}
        if opts.tf_static:
            types[TOPIC_TF_STATIC] = "tf2_msgs/msg/TFMessage"
        types[TOPIC_IMU] = "sensor_msgs/msg/Imu"
        if gt_type != "none":
            types[opts.gt_topic] = GT_MSGTYPES[gt_type]
        if opts.lidar:
            types[lidar_topic] = "sensor_msgs/msg/PointCloud2" if spinning else "sensor_msgs/msg/LaserScan"
        if wheel is not None:
            types[TOPIC_WHEEL] = "nav_msgs/msg/Odometry"
        if gps is not None:
            types[TOPIC_GPS] = "sensor_msgs/msg/NavSatFix"
        if opts.tf_static:
            wr.add_topic(TOPIC_TF_STATIC, types[TOPIC_TF_STATIC], latching=True)
        for topic in (lidar_topic, TOPIC_IMU, TOPIC_WHEEL, opts.gt_topic, TOPIC_GPS):
            if topic in types:
                wr.add_topic(topic, types[topic])

        def put(topic: str, t_ns: int, msg) -> None:
            wr.write(topic, int(t_ns), msg)
            counts[topic] = counts.get(topic, 0) + 1

        if opts.tf_static:
            first_ns = min(start_ns, int(imu.stamps_ns[0]))
            put(TOPIC_TF_STATIC, first_ns, static_transforms(mk, first_ns, sc, gps is not None))
        # small time-ordered streams, merged with the scans window by window
        streams = [((int(s), 1, TOPIC_IMU, i) for i, s in enumerate(imu.stamps_ns))]
        if gt_type != "none":
            streams.append(((int(s), 3, opts.gt_topic, i) for i, s in enumerate(data.gt_ns)))
        if wheel is not None:
            streams.append(((int(s), 2, TOPIC_WHEEL, i) for i, s in enumerate(wheel.stamps_ns)))
        if gps is not None:
            streams.append(((int(s), 4, TOPIC_GPS, i) for i, s in enumerate(gps.stamps_ns)))
        events = heapq.merge(*streams)
        pending = next(events, None)

        def flush(until_ns: int) -> None:
            nonlocal pending
            while pending is not None and pending[0] <= until_ns:
                t, kind, topic, i = pending
                if kind == 1:
                    put(topic, t, mk.imu(t, "imu", imu.gyro_radps[i], imu.accel_mps2[i]))
                elif kind == 3:
                    put(topic, t, gt_message(mk, gt_type, opts.gt_twist, t, data.gt_state, i, gt_poses[i]))
                elif kind == 2:
                    put(topic, t, mk.odometry(t, "odom", "base", wheel.poses_odom_base[i],
                                              (wheel.linear_mps[i], 0.0, 0.0), (0.0, 0.0, wheel.angular_radps[i])))
                else:
                    put(topic, t, gps_message(mk, gps, i))
                pending = next(events, None)

        for k in range(n_scans):
            scan_start = start_ns + k * period
            scan_end = scan_start + period
            flush(scan_end)
            if not opts.lidar:
                pass
            elif spinning:
                scan = spin_scan(sc.world, sc.trajectory, sc.T_base_lidar, sc.lidar, scan_start, start_ns, rng_lidar)
                header_ns = scan_start if opts.header_stamp == "start" else scan_end
                put(lidar_topic, scan_end,
                    mk.pointcloud2(header_ns, "lidar", cloud_array(scan, opts.time_convention, header_ns)))
            else:
                lspec: LaserSpec = sc.lidar
                ranges = laser_scan(sc.world, sc.trajectory, sc.T_base_lidar, lspec, scan_start, start_ns, rng_lidar)
                put(lidar_topic, scan_end, mk.laserscan(scan_start, "lidar", lspec.angle_min_rad,
                                                        lspec.angle_increment_rad, lspec.time_increment_s,
                                                        lspec.period_ns * 1e-9, lspec.min_range_m, lspec.max_range_m,
                                                        ranges))
            if progress is not None:
                progress(period * 1e-9)
        flush(end_ns + NS)
    return types, counts
