"""Message bytes <-> records: decoding (Imu, Odometry, PointCloud2, TF, NavSatFix), encoding, definitions."""
