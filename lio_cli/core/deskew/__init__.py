"""What ``lio deskew`` estimates: the pose spline over a sweep, gyro sweeps, the map of de-skewed scans."""
