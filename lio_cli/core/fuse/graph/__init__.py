"""``--smooth`` as a factor graph over the whole log (GTSAM): nav states and IMU biases at keyframes, combined
preintegrated IMU factors between them, wheel velocity, odometry increment, robust GPS and IMU orientation
factors, a prior from the filter's start; Levenberg-Marquardt in overlapping chunks (``solve``), started from the
3D filter's own states, checked against them (``guard``: the filter's answer stands where the smoothed one
explains the measurements worse), output at the requested stamps by the IMU between keyframes (``output``).

Needs the IMU's gyro and accelerometer (``applies``); the caller keeps the RTS smoother otherwise.
"""

from __future__ import annotations

from ..initial import Start
from ..inputs import FuseOptions
from ..result import FuseResult
from ..timeline import Prepared


def applies(prep: Prepared) -> bool:
    """The graph needs the IMU's gyro and accelerometer (its factors are preintegrated IMU factors)."""
    return prep.imu is not None and {"gyro", "accel"} <= prep.use.get("imu", set())


def smooth_graph(prep: Prepared, o: FuseOptions, start: Start, seed=None) -> FuseResult:
    """The smoothed trajectory at ``prep.out_stamps`` (the filter's where the guard refuses the graph's);
    ``seed`` (keyframe stamps -> x, y, yaw, speed): a planar filter's states to start from (``run``)."""
    from .run import smooth_graph as run  # gtsam's slow import only when smoothing

    return run(prep, o, start, seed)
