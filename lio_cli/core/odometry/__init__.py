"""The per-scan LiDAR-inertial odometry loop (``loop.LioOdometry``) and its steps: the IMU-primed step, the
LiDAR-only step, guards, restart, gaps, the online clock offset, start-up; registration (the only kiss_icp
importer) and degeneracy."""
