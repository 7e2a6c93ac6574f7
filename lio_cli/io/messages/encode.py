"""Build ROS messages (for ROS 1 or ROS 2 typestores) from numpy data, for writing logs."""

from __future__ import annotations

import numpy as np

from ...geometry import pose_to_xyz_quat

# numpy dtype -> sensor_msgs/PointField datatype
_POINTFIELD_TYPES = {"i1": 1, "u1": 2, "i2": 3, "u2": 4, "i4": 5, "u4": 6, "f4": 7, "f8": 8}
_COV0 = np.zeros(9, dtype=np.float64)
_COV36 = np.zeros(36, dtype=np.float64)


class MessageFactory:
    """Message constructors bound to one typestore (ROS 1 headers carry ``seq``, ROS 2 ones do not)."""

    def __init__(self, typestore) -> None:
        self.ts = typestore
        self.T = typestore.types
        self._has_seq = "seq" in self.T["std_msgs/msg/Header"].__dataclass_fields__

    def time(self, ns: int):
        return self.T["builtin_interfaces/msg/Time"](sec=int(ns // 1_000_000_000), nanosec=int(ns % 1_000_000_000))

    def header(self, stamp_ns: int, frame_id: str):
        kw = {"seq": 0} if self._has_seq else {}
        return self.T["std_msgs/msg/Header"](stamp=self.time(stamp_ns), frame_id=frame_id, **kw)

    def vector3(self, v):
        return self.T["geometry_msgs/msg/Vector3"](x=float(v[0]), y=float(v[1]), z=float(v[2]))

    def quaternion(self, q_xyzw):
        return self.T["geometry_msgs/msg/Quaternion"](
            x=float(q_xyzw[0]), y=float(q_xyzw[1]), z=float(q_xyzw[2]), w=float(q_xyzw[3])
        )

    def point(self, v):
        return self.T["geometry_msgs/msg/Point"](x=float(v[0]), y=float(v[1]), z=float(v[2]))

    def pose(self, T: np.ndarray):
        xyz, q = pose_to_xyz_quat(T)
        return self.T["geometry_msgs/msg/Pose"](position=self.point(xyz), orientation=self.quaternion(q))

    def pointcloud2(self, stamp_ns: int, frame_id: str, structured: np.ndarray, height: int = 1,
                    big_endian: bool = False):
        """PointCloud2 from a numpy structured array (its field names, offsets and itemsize are kept)."""
        PointField = self.T["sensor_msgs/msg/PointField"]
        dt = structured.dtype
        fields = []
        for name in dt.names:
            sub, offset = dt.fields[name][0], dt.fields[name][1]
            base = sub.base if sub.subdtype else sub
            count = int(np.prod(sub.shape)) if sub.subdtype else 1
            fields.append(PointField(name=name, offset=int(offset),
                                     datatype=_POINTFIELD_TYPES[base.str[1:]], count=count))
        n = len(structured)
        width = n // height if height else 0
        data = np.frombuffer(np.ascontiguousarray(structured).tobytes(), dtype=np.uint8)
        return self.T["sensor_msgs/msg/PointCloud2"](
            header=self.header(stamp_ns, frame_id), height=int(height), width=int(width), fields=fields,
            is_bigendian=big_endian, point_step=int(dt.itemsize), row_step=int(dt.itemsize * width),
            data=data, is_dense=False,
        )

    def laserscan(self, stamp_ns: int, frame_id: str, angle_min: float, angle_increment: float,
                  time_increment_s: float, scan_time_s: float, range_min: float, range_max: float,
                  ranges: np.ndarray):
        return self.T["sensor_msgs/msg/LaserScan"](
            header=self.header(stamp_ns, frame_id), angle_min=float(angle_min),
            angle_max=float(angle_min + angle_increment * (len(ranges) - 1)), angle_increment=float(angle_increment),
            time_increment=float(time_increment_s), scan_time=float(scan_time_s), range_min=float(range_min),
            range_max=float(range_max), ranges=np.asarray(ranges, dtype=np.float32),
            intensities=np.zeros(0, dtype=np.float32),
        )

    def imu(self, stamp_ns: int, frame_id: str, gyro_radps, accel_mps2):
        return self.T["sensor_msgs/msg/Imu"](
            header=self.header(stamp_ns, frame_id), orientation=self.quaternion((0.0, 0.0, 0.0, 1.0)),
            orientation_covariance=np.array([-1.0] + [0.0] * 8), angular_velocity=self.vector3(gyro_radps),
            angular_velocity_covariance=_COV0.copy(), linear_acceleration=self.vector3(accel_mps2),
            linear_acceleration_covariance=_COV0.copy(),
        )

    def odometry(self, stamp_ns: int, frame_id: str, child_frame_id: str, T: np.ndarray, linear_mps, angular_radps):
        return self.T["nav_msgs/msg/Odometry"](
            header=self.header(stamp_ns, frame_id), child_frame_id=child_frame_id,
            pose=self.T["geometry_msgs/msg/PoseWithCovariance"](pose=self.pose(T), covariance=_COV36.copy()),
            twist=self.T["geometry_msgs/msg/TwistWithCovariance"](
                twist=self.T["geometry_msgs/msg/Twist"](linear=self.vector3(linear_mps), angular=self.vector3(angular_radps)),
                covariance=_COV36.copy(),
            ),
        )

    def twist_stamped(self, stamp_ns: int, frame_id: str, linear_mps, angular_radps):
        return self.T["geometry_msgs/msg/TwistStamped"](
            header=self.header(stamp_ns, frame_id),
            twist=self.T["geometry_msgs/msg/Twist"](linear=self.vector3(linear_mps), angular=self.vector3(angular_radps)),
        )

    def pose_stamped(self, stamp_ns: int, frame_id: str, T: np.ndarray):
        return self.T["geometry_msgs/msg/PoseStamped"](header=self.header(stamp_ns, frame_id), pose=self.pose(T))

    def transform_stamped(self, stamp_ns: int, parent: str, child: str, T: np.ndarray):
        xyz, q = pose_to_xyz_quat(T)
        return self.T["geometry_msgs/msg/TransformStamped"](
            header=self.header(stamp_ns, parent), child_frame_id=child,
            transform=self.T["geometry_msgs/msg/Transform"](translation=self.vector3(xyz), rotation=self.quaternion(q)),
        )

    def navsatfix(self, stamp_ns: int, frame_id: str, lat_deg: float, lon_deg: float, alt_m: float, *,
                  status: int = 0, service: int = 1, covariance_m2=None, covariance_type: int = 0):
        """sensor_msgs/NavSatFix; ``covariance_m2`` (3,3) or (9,) in ENU, zeros (type 0, unknown) by default."""
        cov = _COV0.copy() if covariance_m2 is None else np.asarray(covariance_m2, dtype=np.float64).reshape(9)
        return self.T["sensor_msgs/msg/NavSatFix"](
            header=self.header(stamp_ns, frame_id),
            status=self.T["sensor_msgs/msg/NavSatStatus"](status=int(status), service=int(service)),
            latitude=float(lat_deg), longitude=float(lon_deg), altitude=float(alt_m),
            position_covariance=cov, position_covariance_type=int(covariance_type),
        )

    def tf_message(self, transforms: list):
        return self.T["tf2_msgs/msg/TFMessage"](transforms=list(transforms))
