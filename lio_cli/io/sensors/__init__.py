"""A log as sensor data: topic roles, time-ordered streams, whole-topic series, clocks, IMU units, frames,
trajectory sources, GPS tracks."""
