"""lio: LiDAR-inertial odometry over recorded robot logs."""

__version__ = "0.1.0"
