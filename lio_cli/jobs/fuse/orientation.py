"""Whether the IMU's own orientation enters a run by default: left out (with a note) when its yaw variance says
the heading is unknown (a disturbed magnetometer), or when it does not follow the gyro (a driver without an
attitude filter publishing a constant quaternion: ``core.fuse.orientation_check``)."""

from __future__ import annotations

import numpy as np

from ...core.fuse import ImuSeries
from ...core.fuse.orientation_check import MIN_TURN_RAD, STEPS, STEP_NS, check_orientation

UNKNOWN_HEADING_VAR = 1.0  # rad^2: a yaw sigma over a radian is no heading
FORCE = "--use imu:gyro,accel,orientation forces it in"


def heading_variance(imu) -> float | None:
    """Median yaw variance of the IMU's valid orientations (ROS: covariance about the world z axis)."""
    if imu is None or imu.orientation_cov is None or imu.orientation_valid is None or not np.any(imu.orientation_valid):
        return None
    return float(np.median(imu.orientation_cov[imu.orientation_valid, 2, 2]))


def leave_out_orientation(imu: ImuSeries, use: dict[str, set[str]], notes: list[str]) -> dict | None:
    """Drop ``orientation`` from ``use["imu"]`` where the IMU's orientation cannot be trusted, a note saying why;
    returns the gyro check's figures where it left it out (for metrics), else None."""
    yaw_var = heading_variance(imu)
    if yaw_var is not None and yaw_var > UNKNOWN_HEADING_VAR:
        use["imu"].discard("orientation")
        notes.append(f"IMU orientation left out: its yaw variance (median {yaw_var:g} rad^2) says the heading is "
                     f"unknown; {FORCE}")
        return None
    check = check_orientation(imu)
    if check is None or check.follows is not False:
        return None
    use["imu"].discard("orientation")
    notes.append(f"IMU orientation left out: it does not follow the gyro ({check.disagree} of {check.windows} "
                 f"{STEPS * STEP_NS * 1e-9:g} s windows turning {np.degrees(MIN_TURN_RAD):g} deg or more disagree, "
                 f"by a median {np.degrees(check.median_error_rad):.1f} deg): a frozen or broken attitude; {FORCE}")
    return check.to_dict()
