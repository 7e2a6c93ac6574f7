"""Plain data every layer shares: sensor records, the trajectory type, the calibration.

The names below are loaded on first use (PEP 562): ``lio_cli.model.trajectory`` alone must not pull in the
calibration's pydantic models, which ``lio evaluate`` never needs."""

from ..lazy import lazy_exports

_WHERE = {"Calibration": "calibration", "Extrinsics": "calibration", "ImuBatch": "records",
          "OdometryRecord": "records", "PointCloud": "records", "PoseRecord": "records", "Record": "records",
          "TimeConvention": "records", "TopicInfo": "records", "TransformRecord": "records",
          "Trajectory": "trajectory"}

__all__ = ["Calibration", "Extrinsics", "ImuBatch", "OdometryRecord", "PointCloud", "PoseRecord", "Record",
           "TimeConvention", "TopicInfo", "TransformRecord", "Trajectory"]


__getattr__ = lazy_exports(__name__, _WHERE)
