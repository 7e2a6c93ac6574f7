"""The roll and pitch of a ground robot the planar estimator tracks, from the IMU: the planar filter's poses are
level, but a car on its suspension or a robot on uneven ground tilts by tenths of a degree to degrees, and a level
pose turns its own forward motion into a vertical one (over 0.05 s at 10 m/s, 0.4 deg is 3.4 mm).

The up direction in the base frame, carried by the gyro (``du/dt = -w x u``), is exact over short spans but
drifts with the gyro's bias; the accelerometer less the wheels' own acceleration (``wheel_free_force``) points up
on average but is noisy. In the gyro's start frame the drift is slow, so the accelerometer's up there is fitted by
a smoothing spline (``CROSSOVER_HZ``), carried back into the base frame by the gyro: the fit holds the slow part,
the gyro the rest. The roll is then taken about its median over the log (the IMU's own tilt: its accelerometer
bias, its mount's error); the pitch slower than the heave's crossover is left level, as the height is (``heave``):
a flat path under a pitched pose would climb between two poses what the path does not. So the pitch is the gyro's
above that crossover. Over hills (``grade.estimate``: the slow pitch's climb well above what the sway alone would
climb) the height follows the grade and the pitch keeps it."""

from __future__ import annotations

import numpy as np

from . import heave
from .choose import wheel_free_force
from .tilt_track import running_rotation
from .timeline import Prepared

BLOCK_S = 0.1  # the accelerometer's up averaged over this long for the fit (its crossover is far below 10 Hz)
# below this frequency the accelerometer holds the tilt, above it the gyro: higher, the accelerometer's noise and
# the accelerations the wheels do not see (lateral slip, vibration) tilt the output; lower, the gyro bias's drift
CROSSOVER_HZ = 0.1
CHUNK = 20000  # IMU samples per running product (memory flat in log length)
# the gyro's roll and pitch rates slower than this are taken as its bias (a ground robot's tilt stays bounded)
BIAS_HZ = 0.01


def applies(prep: Prepared) -> bool:
    """Where the heave does (accelerometer selected, wheel speed), with the gyro."""
    return heave.applies(prep) and prep.imu_w_b is not None


def up_directions(prep: Prepared) -> np.ndarray | None:
    """(N,3) unit up direction in the base frame at the IMU stamps; None with too little data. The accelerometer's
    up is left out of the fit where the wheel speed is unknown (its acceleration could not be taken out), and the
    fit is cut at each IMU gap (the gyro carries nothing across one)."""
    t = (prep.imu.stamps_ns - prep.imu.stamps_ns[0]) * 1e-9
    period = float(np.median(np.diff(t)))
    n, m, tb = _blocks(t)
    if m < 8:
        return None
    f = wheel_free_force(prep, t)[0]
    acc_up = f / np.maximum(np.linalg.norm(f, axis=1, keepdims=True), 1e-9)
    w = prep.wheel
    known = np.interp(prep.imu.stamps_ns, w.stamps_ns, np.isfinite(w.velocity_mps[:, 0]).astype(float)) == 1.0
    gap = np.diff(prep.imu.stamps_ns) > (prep.imu_gap_ns if prep.imu_gap_ns > 0 else 5.0 * period * 1e9)
    dt = np.diff(t, prepend=t[0])
    dt[1:][gap] = 0.0
    seen = np.empty_like(acc_up)  # the accelerometer's up in the gyro's start frame
    R0 = np.eye(3)
    for a in range(0, len(t), CHUNK):
        R = running_rotation(prep.imu_w_b[a:a + CHUNK], dt[a:a + CHUNK], R0)
        R0 = R[-1]
        seen[a:a + CHUNK] = np.einsum("nij,nj->ni", R, acc_up[a:a + CHUNK])
    weight = known[:m * n].reshape(m, n).all(axis=1).astype(float)
    piece = np.concatenate([[0], np.cumsum(gap)])[:m * n:n]  # the stretch between IMU gaps each block starts in
    cut = piece[2:] != piece[:-2]  # a second difference over blocks of two stretches
    c = _spline(seen[:m * n].reshape(m, n, 3).mean(axis=1), _smoothing(n * period, CROSSOVER_HZ), weight, cut)
    fit = np.column_stack([np.interp(t, tb, c[:, k]) for k in range(3)])
    up = np.empty_like(acc_up)
    R0 = np.eye(3)
    for a in range(0, len(t), CHUNK):  # the fitted start-frame up, back into the base frame
        R = running_rotation(prep.imu_w_b[a:a + CHUNK], dt[a:a + CHUNK], R0)
        R0 = R[-1]
        up[a:a + CHUNK] = np.einsum("nji,nj->ni", R, fit[a:a + CHUNK])
    return up / np.maximum(np.linalg.norm(up, axis=1, keepdims=True), 1e-9)


def heading_rate_offset(prep: Prepared, up: np.ndarray) -> np.ndarray:
    """(N,) what turns the gyro's base-z rate into the heading's, ``(sin(roll) w_y + cos(roll) w_z) / cos(pitch)``
    (Z-Y-X angles), at the IMU stamps, from the base-frame ``up`` (``up_directions``). On a base that tilts the base z
    axis is not the vertical, and its rate integrated is not the heading: a car's sway alone turned a drive's path
    (docs/benchmarks.md). The pitch rate's bias is taken out first (below ``BIAS_HZ``): times the accelerometer's
    error in the roll it would be a yaw rate bias, and added to the wheels' yaw rate too, no source could tell."""
    w = prep.imu_w_b
    w_y = w[:, 1] - slow_part((prep.imu.stamps_ns - prep.imu.stamps_ns[0]) * 1e-9, w[:, 1], BIAS_HZ)
    return (up[:, 1] * w_y + up[:, 2] * w[:, 2]) / np.maximum(up[:, 1] ** 2 + up[:, 2] ** 2, 1e-6) - w[:, 2]


def _blocks(t: np.ndarray) -> tuple[int, int, np.ndarray]:
    """Samples per ``BLOCK_S`` block, whole blocks, and their mean times, of the sample times ``t`` (s)."""
    period = float(np.median(np.diff(t)))
    n = max(1, int(round(BLOCK_S / period))) if period > 0 else 1
    m = len(t) // n
    return n, m, t[:m * n].reshape(m, n).mean(axis=1)


def slow_part(t: np.ndarray, y: np.ndarray, crossover_hz: float) -> np.ndarray:
    """The part of the samples ``y`` at times ``t`` (s) slower than ``crossover_hz``: their block means fitted by
    the spline, at ``t``."""
    n, m, tb = _blocks(t)
    lam = _smoothing(float(np.median(np.diff(tb))), crossover_hz)
    return np.interp(t, tb, _spline(y[:m * n].reshape(m, n).mean(axis=1)[:, None], lam)[:, 0])


def _smoothing(block_s: float, crossover_hz: float) -> float:
    """The spline's weight on the second difference that halves a sine's amplitude at ``crossover_hz``: the
    penalty ``lam (2 pi f dt)^4`` (per block, ``dt`` the block) against 1 for the data."""
    return 1.0 / (2.0 * np.pi * crossover_hz * block_s) ** 4


def _spline(y: np.ndarray, lam: float, weight: np.ndarray | None = None, cut: np.ndarray | None = None) -> np.ndarray:
    """Columns of ``y`` (one row per block) smoothed: minimise sum weight (c - y)^2 + lam sum (D2 c)^2, D2 the
    second difference of consecutive blocks, its rows where ``cut`` left out (the fit is free across them)."""
    from scipy.linalg import solveh_banded

    m = len(y)
    w = np.ones(m) if weight is None else weight
    keep = np.full(m - 2, lam) if cut is None else np.where(cut, 0.0, lam)
    ab = np.zeros((3, m))  # upper form: ab[2] diagonal, ab[1] first super-diagonal, ab[0] second
    ab[2] = w + 1e-9  # a block of no weight between two cuts: held near zero, not singular
    d = np.array([1.0, -2.0, 1.0])
    # D2^T D2: each row k of D2 touches blocks k, k+1, k+2
    for i in range(3):
        ab[2, i:m - 2 + i] += keep * d[i] ** 2
    ab[1, 1:m - 1] += keep * d[0] * d[1]
    ab[1, 2:m] += keep * d[1] * d[2]
    ab[0, 2:m] += keep * d[0] * d[2]
    return solveh_banded(ab, w[:, None] * y)


def lift(prep: Prepared, result, up_imu: np.ndarray | None = None, pitch_grade: np.ndarray | None = None) -> None:
    """The planar ``result``'s roll and pitch set from the IMU's up direction (``up_imu``, else ``up_directions``),
    its yaw kept, in place, where it applies. ``pitch_grade`` (``grade.estimate``): the pitch keeps the grade the
    path climbs (``heave.lift``); else it is level below the heave's crossover."""
    if not applies(prep) or not len(result.stamps_ns):
        return
    up_imu = up_directions(prep) if up_imu is None else up_imu
    if up_imu is None:
        return
    ti = (prep.imu.stamps_ns - prep.imu.stamps_ns[0]) * 1e-9
    rp = np.column_stack([np.arctan2(up_imu[:, 1], up_imu[:, 2]), -np.arcsin(np.clip(up_imu[:, 0], -1.0, 1.0))])
    # the planar estimator was chosen because the motion stays near a level plane: the roll about its median, the
    # pitch's slow part the grade the height climbs, or level with a level height (module docstring)
    rp[:, 0] -= np.median(rp[:, 0])
    rp[:, 1] -= slow_part(ti, rp[:, 1], heave.CROSSOVER_HZ)
    if pitch_grade is not None:
        rp[:, 1] += pitch_grade
    t = (np.asarray(result.stamps_ns) - prep.imu.stamps_ns[0]) * 1e-9
    roll, pitch = np.interp(t, ti, rp[:, 0]), np.interp(t, ti, rp[:, 1])
    R = result.poses[:, :3, :3]
    yaw = np.arctan2(R[:, 1, 0], R[:, 0, 0])
    cy, sy, cp, sp, cr, sr = np.cos(yaw), np.sin(yaw), np.cos(pitch), np.sin(pitch), np.cos(roll), np.sin(roll)
    result.poses[:, :3, :3] = np.stack([  # Rz(yaw) Ry(pitch) Rx(roll)
        np.stack([cy * cp, cy * sp * sr - sy * cr, cy * sp * cr + sy * sr], axis=1),
        np.stack([sy * cp, sy * sp * sr + cy * cr, sy * sp * cr - cy * sr], axis=1),
        np.stack([-sp, cp * sr, cp * cr], axis=1)], axis=1)
    slow = "level" if pitch_grade is None else "the grade"
    result.info["level"] = {"model": f"gyro carried, accelerometer below a crossover, {slow} below the heave's",
                            "crossover_hz": CROSSOVER_HZ, "level_hz": heave.CROSSOVER_HZ,
                            "tilt_rms_deg": round(float(np.degrees(np.sqrt(np.mean(roll**2 + pitch**2)))), 3)}
