"""Plain data every layer shares: sensor records, the trajectory type, the calibration."""

from .calibration import Calibration, Extrinsics
from .records import (ImuBatch, OdometryRecord, PointCloud, PoseRecord, Record, TimeConvention, TopicInfo,
                      TransformRecord)
from .trajectory import Trajectory

__all__ = ["Calibration", "Extrinsics", "ImuBatch", "OdometryRecord", "PointCloud", "PoseRecord", "Record",
           "TimeConvention", "TopicInfo", "TransformRecord", "Trajectory"]
