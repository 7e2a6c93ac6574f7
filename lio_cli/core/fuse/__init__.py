"""Estimation core of ``lio fuse``: fuse LiDAR odometry, IMU, wheel odometry and GPS into one trajectory.

Entry point: ``fuse(FuseInputs(...), FuseOptions(...)) -> FuseResult``. Estimators (chosen from the data by default: ``choose``): the 3D error-state
EKF (``ekf``), the lecture's planar EKF (``planar``) and complementary filter (``complementary``); with
``FuseOptions(smooth=True)`` (``lio fuse``'s default) smoothed: the factor graph (``graph``) whenever the
accelerometer is used (but for the planar filter on IMU + wheels alone), else the RTS pass over either EKF. Inputs are plain numpy arrays with int64 ns
stamps (``inputs``); nothing here reads files (``lio_cli.io`` is never imported).
"""

from .api import fuse, graph_smooths, judge_gps, whole_log_options
from .choose import EstimatorChoice
from .inputs import (
    ESTIMATORS, MEASUREMENTS, FuseInputs, FuseOptions, GpsSeries, ImuSeries, NoiseOptions, PoseSeries, WheelSeries,
)
from .report import NOTE_REASONS, REJECT_REASONS, SourceReport
from .result import COVARIANCE_LAYOUT, FuseResult

__all__ = [
    "COVARIANCE_LAYOUT", "ESTIMATORS", "EstimatorChoice", "MEASUREMENTS", "NOTE_REASONS", "REJECT_REASONS", "FuseInputs",
    "FuseOptions", "FuseResult", "GpsSeries", "ImuSeries", "NoiseOptions", "PoseSeries", "SourceReport",
    "WheelSeries", "fuse", "graph_smooths", "judge_gps",
    "whole_log_options",
]
