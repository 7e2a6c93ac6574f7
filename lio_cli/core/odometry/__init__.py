"""The per-scan LiDAR-inertial odometry: ``LioOdometry`` (loop) runs the steps (imu_step, lidar_step, guards,
recovery, gaps, bridge, startup) over explicit state (state); registration is the only kiss_icp importer."""

from ...lazy import lazy_exports

__getattr__ = lazy_exports(__name__, {"LioOdometry": "loop", "Diverged": "state", "OdomStats": "state",
                                      "ScanResult": "state"})

__all__ = ["Diverged", "LioOdometry", "OdomStats", "ScanResult"]
