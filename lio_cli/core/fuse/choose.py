"""The default estimator, chosen from the data: ``planar`` when the motion stays near a plane, ``ekf`` otherwise.

A wheeled ground robot (wheel speed with the non-holonomic constraint) whose motion the sources show to stay
near a plane gets the planar EKF: on such a log the 3D EKF has nothing to gain from the vertical and much to
lose (wheel scale errors and slip leak through the accelerometer biases into roll, pitch and yaw). Evidence,
all from the motion sources (never the GPS altitude, which wanders by tens of metres on a consumer receiver):

- the gravity direction in the base frame, averaged over ``WINDOW_S`` with the wheels' own acceleration
  (forward ``dv/dt``, centripetal ``v * yaw rate``) removed: its wander (95th percentile of the angle to its
  median) is the body's roll and pitch on the ground; windows where the wheels accelerate by more than
  ``SLIP_MPS2`` beyond what the IMU feels (a slip) are left out;
- the climb: the wheel speed times the sine of that pitch (less its median, a mounting offset), integrated:
  its extent is how far the motion leaves a plane;
- odometry poses: their vertical extent.

Beside odometry and an accelerometer, ``planar`` only where the wheels agree with the odometry (their scale within
three standard errors of 1, no slip: ``graph.wheels.odometry_agreement``): the data cannot then tell which is off,
and the planar filter keeps the wheels' speed (``wheels_agree_with_odometry`` in the evidence). Where they
disagree, the 3D filter, whose factor graph weighs the wheels' scale and slips against the odometry.

Everything else is ``ekf``: no wheels (handheld, drone), a wheel twist with lateral speed (drone, holonomic
base), or a ground robot whose tilt or climb exceeds the thresholds below.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Callable

import numpy as np

from .timeline import Prepared

WINDOW_S = 1.0  # gravity is averaged over this long a window (vibration and short accelerations average out)
SLIP_MPS2 = 3.0  # wheel acceleration the IMU did not feel, beyond which a window is a slip
MAX_TILT_DEG = 8.0  # 95th percentile of the gravity direction's wander a planar platform may show
MIN_CLIMB_M = 0.5  # vertical extent always taken as planar (bumps, the estimate's own noise) ...
# ... or this share of the distance travelled, whichever is larger, where the accelerometer measured the wheels'
# scale (its axes agree with the wheels'): above a flat drive's evidence, below a car's over hills a metre high
# (docs/benchmarks.md, "Hills")
CLIMB_SHARE = 0.004
# ... this share where it could not (the pitch it reads is then no evidence), and for the odometry's height (a
# scan matcher's drifts with its pitch)
UNCHECKED_CLIMB_SHARE = 0.01


@dataclass(frozen=True)
class EstimatorChoice:
    name: str
    reason: str
    evidence: dict


def wheel_free_force(prep: Prepared, t: np.ndarray,
                     wheel_scale: float = 1.0) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The specific force at the IMU stamps (seconds ``t``) less the base's own acceleration the wheels give
    (forward ``dv/dt``, centripetal ``v w_z``); the wheel speed ``v`` there and its ``dv/dt``."""
    speed = wheel_scale * np.nan_to_num(prep.wheel.velocity_mps[:, 0])
    v = np.interp(prep.imu.stamps_ns, prep.wheel.stamps_ns, speed)
    f = prep.imu_f_b.copy()
    a_wheel = np.gradient(v, t)
    f[:, 0] -= a_wheel  # forward acceleration of the base
    f[:, 1] -= v * prep.imu_w_b[:, 2]  # centripetal
    return f, v, a_wheel


def gravity_evidence(prep: Prepared, dilate: int = 0, wheel_scale: float = 1.0,
                     slip_spans_ns: np.ndarray | None = None, level_fit: bool = False) -> dict | None:
    """Tilt wander (deg), climb extent and path length (m) from the IMU and the wheels; None without both.
    ``dilate``: windows left out on each side of a slip's too (its onset and end). ``wheel_scale``: the wheel
    speed's true scale where another source found it; ``slip_spans_ns`` (rows start, end): spans another source
    found slipping, their windows left out as the IMU's slips are. ``level_fit``: the climb's level (the
    mounting's pitch) fitted in least squares along the distance, not the windows' median (which a few dozen
    windows leave off by tenths of a percent: tenths of a metre over 70 m)."""
    imu, w = prep.imu, prep.wheel
    if imu is None or prep.imu_f_b is None or "accel" not in prep.use.get("imu", ()) or w is None or len(w) < 2:
        return None
    t = (imu.stamps_ns - imu.stamps_ns[0]) * 1e-9
    period = float(np.median(np.diff(t))) if len(t) > 1 else 0.0
    n = int(round(WINDOW_S / period)) if period > 0 else 0
    m = len(t) // n if n else 0
    if m < 2:
        return None
    f, v, a_wheel = wheel_free_force(prep, t, wheel_scale)
    f_win = f[:m * n].reshape(m, n, 3).mean(axis=1)
    up = f_win / np.maximum(np.linalg.norm(f_win, axis=1, keepdims=True), 1e-9)
    # a wheel slip: the wheels' speed jumps by metres per second in a fraction of one while the IMU feels no
    # such acceleration; those windows say nothing about the ground
    unfelt = np.abs(a_wheel) - np.abs(prep.imu_f_b[:, 0] - np.median(prep.imu_f_b[:, 0]))
    slip = (unfelt[:m * n].reshape(m, n) > SLIP_MPS2).any(axis=1)
    if slip_spans_ns is not None and len(slip_spans_ns):
        w0 = imu.stamps_ns[:m * n:n]
        w1 = imu.stamps_ns[n - 1:m * n:n]
        slip |= ((w0[:, None] <= slip_spans_ns[None, :, 1]) & (w1[:, None] >= slip_spans_ns[None, :, 0])).any(axis=1)
    for _ in range(dilate):
        slip = slip | np.r_[False, slip[:-1]] | np.r_[slip[1:], False]
    if slip.all():
        slip[:] = False
    med = np.median(up[~slip], axis=0)
    med /= max(float(np.linalg.norm(med)), 1e-9)
    up[slip] = med
    tilt = np.degrees(np.arccos(np.clip(up[~slip] @ med, -1.0, 1.0)))
    v_win = v[:m * n].reshape(m, n).mean(axis=1)
    climb = np.cumsum(v_win * (up[:, 0] - med[0]) * n * period)  # forward axis's share of "up" is sin(pitch)
    if level_fit:  # a level off by c climbs c per metre of the windows kept
        x = np.cumsum(np.where(slip, 0.0, v_win) * n * period)
        if np.ptp(x) > 0:
            climb = climb - np.polyfit(x, climb, 1)[0] * x
    return {"tilt_p95_deg": round(float(np.percentile(tilt, 95)), 2), "climb_m": round(float(np.ptp(climb)), 2),
            "path_m": round(float(np.sum(np.abs(v_win)) * n * period), 1), "slip_windows": int(slip.sum())}


def _odom_evidence(prep: Prepared) -> dict | None:
    od = prep.odom
    if od is None or len(od) < 2:
        return None
    p = od.poses[:, :3, 3]
    return {"odom_vertical_m": round(float(np.ptp(p[:, 2])), 2),
            "odom_path_m": round(float(np.linalg.norm(np.diff(p[:, :2], axis=0), axis=1).sum()), 1)}


def choose_estimator(prep: Prepared, scale_measured: Callable[[], bool] = lambda: False,
                     odometry_agrees: Callable[[], tuple[bool, str]] = lambda: (False, "not weighed")
                     ) -> EstimatorChoice:
    """``planar`` or ``ekf`` for the prepared sources, with a one-line reason (module docstring).
    ``scale_measured``: whether the accelerometer measures the wheels' scale (``wheel_slip``), so that the climb it
    reads is held to ``CLIMB_SHARE`` of the distance, not ``UNCHECKED_CLIMB_SHARE``; asked only where that
    decides. ``odometry_agrees``: whether, and why, the wheels agree with the odometry; asked beside one."""
    wheel_use = prep.use.get("wheel", set())
    if "wheel" not in prep.use or prep.wheel is None:
        return EstimatorChoice("ekf", "no wheel odometry: the motion is taken as 3D (handheld, drone)", {})
    if "velocity" in wheel_use or "speed" not in wheel_use:
        return EstimatorChoice("ekf", "the wheel twist carries lateral speed (a drone or holonomic base): 3D", {})
    beside = ""
    if "odom" in prep.use and "accel" in prep.use.get("imu", ()):
        agrees, why = odometry_agrees()
        if not agrees:
            return EstimatorChoice("ekf", f"odometry poses and an accelerometer, {why}: the 3D filter, whose graph "
                                          "weighs the wheels' scale and slips against the odometry", {})
        beside = f"; beside the odometry, the wheels agreeing with it ({why})"
    ev: dict = {"wheels_agree_with_odometry": True} if beside else {}
    g, od = gravity_evidence(prep), _odom_evidence(prep)
    ev.update(g or {})
    ev.update(od or {})
    if od is not None:
        limit = max(MIN_CLIMB_M, UNCHECKED_CLIMB_SHARE * od["odom_path_m"])
        if od["odom_vertical_m"] > limit:
            return EstimatorChoice("ekf", f"the odometry climbs {od['odom_vertical_m']:.2f} m over "
                                          f"{od['odom_path_m']:.0f} m (more than {limit:.2f} m): 3D", ev)
    if g is not None:
        limit = max(MIN_CLIMB_M, UNCHECKED_CLIMB_SHARE * g["path_m"])
        if max(MIN_CLIMB_M, CLIMB_SHARE * g["path_m"]) < g["climb_m"] <= limit and scale_measured():
            limit = max(MIN_CLIMB_M, CLIMB_SHARE * g["path_m"])
        if g["tilt_p95_deg"] > MAX_TILT_DEG:
            return EstimatorChoice("ekf", f"the ground tilts the robot by {g['tilt_p95_deg']:.1f} deg (95th "
                                          f"percentile, more than {MAX_TILT_DEG:g}): 3D", ev)
        if g["climb_m"] > limit:
            return EstimatorChoice("ekf", f"wheels and IMU climb {g['climb_m']:.2f} m over {g['path_m']:.0f} m "
                                          f"(more than {limit:.2f} m): 3D", ev)
        return EstimatorChoice("planar", f"a wheeled robot near a plane: tilt {g['tilt_p95_deg']:.1f} deg (95th "
                                         f"percentile), climb {g['climb_m']:.2f} m over {g['path_m']:.0f} m"
                                         f"{beside}", ev)
    if od is not None:
        return EstimatorChoice("planar", f"a wheeled robot near a plane: the odometry climbs "
                                         f"{od['odom_vertical_m']:.2f} m over {od['odom_path_m']:.0f} m{beside}", ev)
    return EstimatorChoice("planar", "a wheeled robot without an accelerometer or odometry: nothing measures 3D "
                                     "motion", ev)
