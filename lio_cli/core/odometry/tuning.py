"""The odometry loop's tuning constants (the estimators' own are in bootstrap, clock_offset and registration)."""

from __future__ import annotations

import numpy as np

# the pose's bookkeeping
MIN_VELOCITY_DT_S = 0.02  # a velocity from two poses needs at least this long an interval between them
WHEEL_KEEP_NS = 1_000_000_000  # wheel records older than this behind the last scan (or the start-up window) are dropped
IMU_PRIOR_CORRESPONDENCE_M = 0.5  # correspondence gate of the registration primed by the IMU state

# guards of the IMU-primed step
MAX_JUMP_M = 1.0  # a registration this far from the IMU prediction within one scan has failed...
MAX_JUMP_RAD = 0.35  # ...or turned this far from it
NIS_LIMIT = 100.0  # a pose innovation this far outside its covariance (chi-square, 6 dof) is doubted...
NIS_SCANS = 3  # ...and this many doubted scans in a row drop the IMU state
MAX_BIAS_GYRO_RADPS = 0.5  # a state whose biases pass these is no longer plausible
MAX_BIAS_ACCEL_MPS2 = 3.0
PREDICT_MIN_MAP_SCANS = 20  # a map this young registers every scan (no scan takes its IMU prediction)

# the first start-up window without wheels: LiDAR-only increments that misfit the IMU by more than this (RMS)...
START_MISFIT_M = 0.15
MAX_START_SLIDE_S = 3.0  # ...slide the window, for at most this long, and its scans are replayed from the first

# wheels
MOVING_MPS = 0.3  # faster than this, an exactly-zero wheel twist is not a wheel at rest
MOVING_M = 0.3  # wheels that read exactly zero while the start-up window moved this far are no wheels
WHEEL_SPEED_HALF_WINDOW_NS = 60_000_000  # a start-up scan's wheel speed: records this close to its stamp
WHEEL_DELTA_LEAD_NS = 100_000_000  # a wheel prior's twist: records from this long before the interval
WHEEL_UPDATE_TAIL_NS = 20_000_000  # a wheel update's twist: records up to this long after the scan

# LiDAR-only steps
MAP_RESTART_SCANS = 3  # a one-scan map that this many scans in a row cannot match is dropped...
MAX_MAP_RESTARTS = 3  # ...at most this often per run
GYRO_PRIOR_GATE_M = 1.0  # gate of a LiDAR-only scan primed by the gyro (translation: constant velocity)...
GYRO_PRIOR_JUMP_M = 2.0  # ...which has failed when it lands this far from its guess...
GYRO_PRIOR_JUMP_RAD = np.radians(10.0)  # ...or turned this far from it; and...
UNKNOWN_SPEED_GATE_M = 6.0  # ...before the speed is known also tried this wide (kiss-icp's first gate, 3 x 2 m)...
UNKNOWN_SPEED_SCANS = 30  # ...over the first this many LiDAR-only scans, before an IMU state ever started...
UNKNOWN_SPEED_SHIFT_M = 0.3  # ...and kept, in a pass without a start-up window, when it moves this far from the guess

# LiDAR gaps bridged by the IMU state
BRIDGE_STEP_NS = 100_000_000  # the wheel speed corrects a bridged state this often (the last scan interval if known)
DRIFT_SIGMA_MPS = 0.05  # velocity error of a converged state: sigma_v T of drift over a gap of T...
DRIFT_SIGMA_MPS2 = 0.1  # ...plus sigma_a T^2 / 2 (tilt, accelerometer bias)
GATE_M = 0.5  # the IMU prior's fixed gate, widened by 3 drifts after a gap...
MAX_BRIDGE_GATE_M = 2.0  # ...up to kiss-icp's initial adaptive threshold

# scans over an IMU gap: registered from yaw hypotheses around constant velocity
BLIND_YAWS_RAD = np.radians([0.0, 8.0, -8.0, 16.0, -16.0, 24.0, -24.0])
BLIND_GATE_M = 1.0
RESEED_SIGMA_RAD = 0.05  # the state re-seeded from such a scan: its pose and velocity are this uncertain
RESEED_SIGMA_M = 0.1
RESEED_SIGMA_MPS = 0.5
