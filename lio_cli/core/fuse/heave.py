"""The height of a ground robot the planar estimator tracks: its heave, from the accelerometer, about a level.

The planar filter's output is flat (z zero), but a wheeled robot on uneven ground or a car on its suspension
moves up and down by centimetres: on such logs that was most of the fused error. The accelerometer measures
it: along "up" in the base frame (the specific force less the wheels' own acceleration, forward ``dv/dt`` and
centripetal ``v * yaw rate``, whose direction is gravity's), the specific force is ``g + z''``. Errors in that
direction enter ``z''`` only times the horizontal acceleration or to second order, so a direction averaged over
``BLOCK_S`` blocks and smoothed over ``UP_SMOOTH_BLOCKS`` serves.

The heights at the blocks are the least-squares fit of ``z'' = a`` (the block's vertical acceleration less its
mean over ``HIGHPASS_S``: gravity's magnitude and the accelerometer's bias) beside a prior holding the height to
a level (the estimator was chosen because the motion stays near a plane, ``choose``), with the sigma that puts
the two's crossover at ``CROSSOVER_HZ``: heights faster than that come from the accelerometer, slower ones stay at
the level. A linear, pentadiagonal system: solved in one banded Cholesky. Over hills the level is the path's
climb (``climb``: its forward distance times the grade ``grade.estimate`` finds) instead of a flat one.
"""

from __future__ import annotations

import numpy as np

from .choose import wheel_free_force
from .timeline import Prepared

BLOCK_S = 0.02  # the heights' grid: IMU samples averaged over this long (heave is below a few Hz)
# the up direction averaged over this many blocks (its noise enters times the horizontal acceleration)
UP_SMOOTH_BLOCKS = 5
HIGHPASS_S = 10.0  # the vertical acceleration's mean over this long is gravity and bias, not motion
# below this frequency the level holds the height, above it the accelerometer: lower, the vertical acceleration's
# slow errors (tilt times horizontal acceleration, the wheels' acceleration, bias) outweigh the heave they carry
CROSSOVER_HZ = 0.12
MAX_BLOCK_GAP_S = 0.5  # blocks further apart are not tied by an acceleration


def applies(prep: Prepared) -> bool:
    """Accelerometer and wheel speed both in use."""
    return (prep.imu is not None and prep.imu_f_b is not None
            and ("accel" in prep.use.get("imu", ()) or prep.heave_accel)
            and prep.wheel is not None and len(prep.wheel) > 1 and len(prep.imu) > 4)


def heights(prep: Prepared, stamps_ns: np.ndarray, climb: np.ndarray | None = None,
            wheels: bool = True) -> np.ndarray | None:
    """The heave (m, about the level) at ``stamps_ns``; None without enough data. ``climb`` (m, at ``stamps_ns``):
    the height the level follows (``climb``), else zero. ``wheels`` False: the up direction is the specific
    force's own, the wheels' acceleration left in (the vertical then takes ``a_h^2 / 2g`` of a horizontal one, but
    no slip of the wheels)."""
    t_ns = prep.imu.stamps_ns
    t = (t_ns - t_ns[0]) * 1e-9
    period = float(np.median(np.diff(t)))
    n = max(1, int(round(BLOCK_S / period))) if period > 0 else 0
    m = len(t) // n if n else 0
    if m < 8:
        return None
    f = prep.imu_f_b
    cut = m * n
    g_blk = (wheel_free_force(prep, t)[0] if wheels else f)[:cut].reshape(m, n, 3).mean(axis=1)
    f_blk = f[:cut].reshape(m, n, 3).mean(axis=1)
    tb = t[:cut].reshape(m, n).mean(axis=1)
    up = _moving_mean(g_blk, UP_SMOOTH_BLOCKS)
    up /= np.maximum(np.linalg.norm(up, axis=1, keepdims=True), 1e-9)
    a = np.einsum("ij,ij->i", f_blk, up)
    a = a - _moving_mean(a[:, None], max(1, int(round(HIGHPASS_S / (n * period)))))[:, 0]
    # with the block's acceleration noise as the unit (the heights do not depend on its size), the level's sigma
    # per second that puts the crossover at CROSSOVER_HZ
    level = None if climb is None else np.interp(tb, (np.asarray(stamps_ns) - t_ns[0]) * 1e-9, climb)
    z = _solve(tb, a, 1.0, np.sqrt(n * period) / (2.0 * np.pi * CROSSOVER_HZ) ** 2, level)
    return np.interp((np.asarray(stamps_ns) - t_ns[0]) * 1e-9, tb, z)


def _moving_mean(x: np.ndarray, k: int) -> np.ndarray:
    """Centred mean over ``k`` rows (shorter at the ends), per column."""
    if k <= 1:
        return x.copy()
    c = np.vstack([np.zeros((1, x.shape[1])), np.cumsum(x, axis=0)])
    i = np.arange(len(x))
    lo, hi = np.maximum(i - k // 2, 0), np.minimum(i + k - k // 2, len(x))
    return (c[hi] - c[lo]) / (hi - lo)[:, None]


def _solve(tb: np.ndarray, a: np.ndarray, sigma_a: float, level_sigma: float,
           level: np.ndarray | None = None) -> np.ndarray:
    """Heights z at ``tb`` minimising sum ((D2 z - a) / sigma_a)^2 + sum dt (z - level)^2 / level_sigma^2 (D2: the
    second difference on the grid, not across gaps; ``level`` zero if None)."""
    from scipy.linalg import solveh_banded

    m = len(tb)
    h1, h2 = tb[1:-1] - tb[:-2], tb[2:] - tb[1:-1]
    ok = (h1 < MAX_BLOCK_GAP_S) & (h2 < MAX_BLOCK_GAP_S)
    # rows k: coefficients on z[k], z[k+1], z[k+2] of the second difference centred on k+1
    c0, c2 = 2.0 / (h1 * (h1 + h2)), 2.0 / (h2 * (h1 + h2))
    c1 = -(c0 + c2)
    wa = np.where(ok, 1.0 / sigma_a**2, 0.0)
    dt = np.gradient(tb)
    ab = np.zeros((3, m))  # upper form: ab[2] diagonal, ab[1] first super-diagonal, ab[0] second
    rhs = np.zeros(m)
    ab[2] += dt / level_sigma**2
    if level is not None:
        rhs += dt * level / level_sigma**2
    cs = (c0, c1, c2)
    for i in range(3):
        ab[2, i:m - 2 + i] += wa * cs[i] ** 2
        rhs[i:m - 2 + i] += wa * cs[i] * a[1:-1]
    ab[1, 1:m - 1] += wa * c0 * c1
    ab[1, 2:m] += wa * c1 * c2
    ab[0, 2:m] += wa * c0 * c2
    return solveh_banded(ab, rhs)


def climb(prep: Prepared, result, pitch_grade: np.ndarray) -> np.ndarray:
    """(M,) the height (m) the planar ``result``'s path climbs at its stamps: each step's forward distance times the
    grade (``pitch_grade``, a pitch in rad at the IMU stamps, ``grade.estimate``)."""
    p = result.poses
    step = np.diff(p[:, :2, 3], axis=0)
    forward = step[:, 0] * p[:-1, 0, 0] + step[:, 1] * p[:-1, 1, 0]
    mid = 0.5 * (np.asarray(result.stamps_ns[1:], float) + np.asarray(result.stamps_ns[:-1], float))
    pitch = np.interp(mid, prep.imu.stamps_ns.astype(float), pitch_grade)
    return np.concatenate([[0.0], np.cumsum(-forward * np.sin(pitch))])


def lift(prep: Prepared, result, pitch_grade: np.ndarray | None = None) -> None:
    """The planar ``result``'s heights set to the heave (``heights``) where it applies, in place: about the path's
    climb (``climb``) where ``pitch_grade`` is given, else about a level."""
    if not applies(prep) or not len(result.stamps_ns):
        return
    level = None if pitch_grade is None else climb(prep, result, pitch_grade)
    z = heights(prep, result.stamps_ns, level)
    if z is None:
        return
    result.poses[:, 2, 3] = z - z[0]
    about = "a level" if level is None else "the grade's climb"
    result.info["heave"] = {"model": f"accelerometer about {about}", "crossover_hz": CROSSOVER_HZ,
                            "rms_m": round(float(np.std(z if level is None else z - level)), 4)}
