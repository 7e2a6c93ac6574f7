"""Where the base stands still after the start: a car at a light, a robot pausing, a log that ends parked.

A span is at rest where, over every ``WINDOW_S`` window of it, the IMU reads as at rest (the thresholds the
standing start uses, ``initial``) and the wheels report no speed in any direction they give and a measured yaw
rate of none (without wheels, the odometry neither moves nor turns); at least ``MIN_REST_S`` long, ``EDGE_S``
trimmed from each end. At constant velocity an IMU reads exactly as at rest, and a wheel message without a yaw
rate cannot tell a turn on the spot from rest: those witness none. The spans before the base first moves are
the start's, which ``initial_state`` measured already, and are left out. There the true turn rate is zero, so the gyro's reading is
its bias: the filters take a zero turn rate, the graph zero motion between keyframes, and the smoother carries a
bias measured at a stop back over the whole log (a moving start measures none).
"""

from __future__ import annotations

import numpy as np

from .initial import STILL_SPEED_MPS, imu_quiet
from .timeline import Prepared

WINDOW_S = 0.5
MIN_REST_S = 0.5
EDGE_S = 0.25  # the last of the braking and the first of the pull-away, left out
STILL_YAW_RADPS = 0.01  # the wheels' yaw rate of a base at rest (a slow turn on the spot is not rest)
# the turn rate at rest is zero but for what an idling engine or a gust turns the base by: the zero-rate
# pseudo-measurement's sigma (its many samples, not this, measure the bias)
REST_RATE_SIGMA_RADPS = 1e-2
REST_POSITION_SIGMA_M = 1e-3  # the graph's zero motion between two keyframes at rest ...
REST_ROTATION_SIGMA_RAD = 1e-4  # ... and zero turn (a vibration's turns average out over a keyframe interval)
REST_VELOCITY_SIGMA_MPS = 1e-3


def rest_spans(prep: Prepared, gravity_mps2: float) -> np.ndarray:
    """(n, 2) int64 [start, end] ns of the spans at rest after the start (module docstring); (0, 2) where none."""
    none = np.zeros((0, 2), np.int64)
    imu = prep.imu
    wheel = prep.wheel if "wheel" in prep.use and prep.wheel is not None and len(prep.wheel) else None
    odom = prep.odom if "odom" in prep.use and prep.odom is not None and len(prep.odom) > 1 else None
    if imu is None or prep.imu_w_b is None or "gyro" not in prep.use.get("imu", ()) or (wheel is None and odom is None):
        return none
    t = imu.stamps_ns
    period = float(np.median(np.diff(t))) if len(t) > 1 else 0.0
    n = int(round(WINDOW_S * 1e9 / period)) if period > 0 else 0
    m = len(t) // n if n >= 10 else 0
    if m < 2:
        return none
    w = prep.imu_w_b[:m * n].reshape(m, n, 3)
    f = imu.accel_mps2[:m * n].reshape(m, n, 3)
    a, b = t[:m * n:n], t[n - 1:m * n:n]
    still = imu_quiet(w, f, gravity_mps2)[0] & (b - a <= 1.5 * WINDOW_S * 1e9)  # and no IMU gap inside
    still_base, moved = _wheels_still(wheel, a, b) if wheel is not None else _odom_still(odom, a, b)
    still &= still_base
    # the spans before the base first moves are the start's: ``initial_state`` measured them (or a driver that
    # started late kept them from it)
    first_move = int(np.argmax(moved)) if moved.any() else m
    spans = []
    k = 0
    while k < m:
        if not still[k]:
            k += 1
            continue
        j = k
        while j + 1 < m and still[j + 1] and a[j + 1] - b[j] <= 2.0 * period:  # no IMU gap between
            j += 1
        if k > first_move:
            spans.append((int(a[k]), int(b[j])))
        k = j + 1
    edge = int(EDGE_S * 1e9)
    out = [(s + edge, e - edge) for s, e in spans if (e - s) - 2 * edge >= MIN_REST_S * 1e9]
    return np.array(out, np.int64).reshape(-1, 2)


def _wheels_still(wheel, a: np.ndarray, b: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Per window [a, b]: (at rest: wheel messages inside, every one with no speed in any direction it gives and
    a yaw rate, measured, of none; moved: one of them reports motion). A message without a yaw rate cannot tell a
    turn on the spot from rest, so it witnesses no rest."""
    v = wheel.velocity_mps
    speed = np.hypot(np.nan_to_num(v[:, 0], nan=np.inf), np.hypot(np.nan_to_num(v[:, 1]), np.nan_to_num(v[:, 2])))
    yaw = np.abs(wheel.yaw_rate_radps)
    moving = (speed >= STILL_SPEED_MPS) | (yaw >= STILL_YAW_RADPS)  # NaN compares False: not seen moving
    unsure = np.isnan(yaw) | np.isinf(speed)
    i0, i1 = np.searchsorted(wheel.stamps_ns, a, "left"), np.searchsorted(wheel.stamps_ns, b, "right")
    n_moving, n_unsure = np.cumsum(np.r_[0, moving]), np.cumsum(np.r_[0, moving | unsure])
    moved = n_moving[i1] > n_moving[i0]
    return (i1 > i0) & (n_unsure[i1] == n_unsure[i0]), moved


def _odom_still(odom, a: np.ndarray, b: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Per window [a, b]: (at rest: the odometry's poses within it, two at least, moved and turned less than a
    base at rest; moved: they moved or turned more)."""
    i0, i1 = np.searchsorted(odom.stamps_ns, a, "left"), np.searchsorted(odom.stamps_ns, b, "right") - 1
    ok = i1 > i0
    i0c, i1c = np.minimum(i0, len(odom) - 1), np.clip(i1, 0, len(odom) - 1)
    d = np.linalg.norm(odom.poses[i1c, :3, 3] - odom.poses[i0c, :3, 3], axis=1)
    dR = np.einsum("nji,njk->nik", odom.poses[i0c, :3, :3], odom.poses[i1c, :3, :3])
    angle = np.arccos(np.clip((np.trace(dR, axis1=1, axis2=2) - 1.0) / 2.0, -1.0, 1.0))
    dt = np.maximum((odom.stamps_ns[i1c] - odom.stamps_ns[i0c]) * 1e-9, 1e-9)
    still = (d / dt < STILL_SPEED_MPS) & (angle / dt < STILL_YAW_RADPS)
    return ok & still, ok & ~still


def at_rest(spans: np.ndarray | None, stamps_ns: np.ndarray) -> np.ndarray:
    """Per stamp: inside one of ``spans``."""
    if spans is None or not len(spans):
        return np.zeros(len(stamps_ns), bool)
    j = np.searchsorted(spans[:, 0], stamps_ns, "right") - 1
    return (j >= 0) & (stamps_ns <= spans[np.maximum(j, 0), 1])


def pieces_joined(pieces: list[tuple[dict | None, int, int]]) -> np.ndarray:
    """The spans of a log fused in pieces: each piece's ``info["rest"]`` clipped to the span [a, b] it kept,
    a stop cut by a seam joined again."""
    out: list[list[int]] = []
    for info, a, b in pieces:
        for s, e in (info or {}).get("span_ns", []):
            s, e = max(int(s), a), min(int(e), b)
            if s >= e:
                continue
            if out and s <= out[-1][1] + 1:
                out[-1][1] = max(out[-1][1], e)
            else:
                out.append([s, e])
    return np.array(out, np.int64).reshape(-1, 2)


def summary(spans: np.ndarray | None) -> dict | None:
    """The spans for the metrics, or None without any."""
    if spans is None or not len(spans):
        return None
    seconds = float(np.sum(spans[:, 1] - spans[:, 0])) * 1e-9
    return {"spans": len(spans), "seconds": round(seconds, 2), "span_ns": spans.tolist(),
            "why": f"{len(spans)} stop{'s' if len(spans) > 1 else ''} after the start ({seconds:.1f} s) where the "
                   f"wheels (or odometry) and the IMU stood still: the gyro's reading there taken as its bias"}


__all__ = ["at_rest", "pieces_joined", "rest_spans", "summary"]
