"""The IMU at rest: find a still stretch, then read gyro bias, gravity, the accelerometer bias along gravity and
the white-noise densities from it.

At rest the gyro reads its bias plus white noise (the earth's rotation, 7.3e-5 rad/s, is below what MEMS gyros
resolve and is left in the bias), and the accelerometer reads ``R_imu_world (0, 0, g) + b_a`` plus noise. With a
single attitude only the norm ``|g + b_a . up|`` is seen: the bias along gravity and the gravity magnitude are
not separable, so the bias is read against a nominal gravity (9.81 m/s^2 unless given) and the horizontal
bias components stay unknown (they look like tilt).

Noise densities are continuous-time (``gyro``: rad/s/sqrt(Hz), ``accel``: m/s^2/sqrt(Hz)): the discrete
standard deviation of the (linearly detrended) samples times sqrt(sample interval), the same definition as the
simulator's ``ImuSpec`` and Kalibr's ``*_noise_density``.
"""

from __future__ import annotations

import math

from dataclasses import dataclass

import numpy as np

from ...errors import InputError
from .common import NS_PER_S, CalibrationResult, check_imu, time_ranges_text, true_runs

GRAVITY_MPS2 = 9.81


@dataclass(frozen=True)
class StillOptions:
    """How stillness is judged: over windows of ``window_s``, each axis' standard deviation below the limits,
    the mean turn rate below ``gyro_rate_max_radps`` (allows for bias) and the specific force within
    ``accel_norm_tol_mps2`` of gravity. The stretch kept is the first still run, trimmed by ``trim_s`` at
    each end, and must last ``min_duration_s``."""

    window_s: float = 0.4
    gyro_std_max_radps: float = 0.02
    accel_std_max_mps2: float = 0.15
    gyro_rate_max_radps: float = 0.05
    accel_norm_tol_mps2: float = 1.0
    trim_s: float = 0.1
    min_duration_s: float = 1.0


@dataclass(frozen=True, eq=False)
class ImuStatic(CalibrationResult):
    """What the still stretch [start_ns, end_ns] says. Vectors are in the IMU frame, sigmas are 1-sigma."""

    start_ns: int
    end_ns: int
    samples: int
    gyro_bias_radps: np.ndarray
    gyro_bias_sigma_radps: np.ndarray
    up_imu: np.ndarray  # unit vector: the world's up in the IMU frame (mean specific force direction)
    specific_force_norm_mps2: float
    gravity_mps2: float  # the nominal gravity the bias is read against
    accel_bias_along_gravity_mps2: float
    accel_bias_along_gravity_sigma_mps2: float
    accel_bias_mps2: np.ndarray  # the part along up (horizontal components are not observable at rest)
    gyro_noise_density: np.ndarray  # rad/s/sqrt(Hz), per axis
    accel_noise_density: np.ndarray  # m/s^2/sqrt(Hz), per axis
    noise_density_rel_sigma: float  # relative 1-sigma of each density
    notes: tuple[str, ...]


def still_mask(stamps_ns: np.ndarray, gyro_radps: np.ndarray, accel_mps2: np.ndarray,
               opts: StillOptions = StillOptions(), gravity_mps2: float = GRAVITY_MPS2) -> np.ndarray:
    """Per sample: is the window of ``opts.window_s`` centred on it still?"""
    dt_s = float(np.median(np.diff(stamps_ns))) / NS_PER_S
    w = max(3, int(round(opts.window_s / dt_s)))
    n = len(stamps_ns)
    if n < w:
        return np.zeros(n, bool)
    ok = _still(*_moving_mean_std(gyro_radps, w), *_moving_mean_std(accel_mps2, w), opts, gravity_mps2)
    # window k covers samples k..k+w-1 and judges its centre k + w//2; the ends take the nearest verdict
    return ok[np.clip(np.arange(n) - w // 2, 0, len(ok) - 1)]


def moving_share(stamps_ns: np.ndarray, gyro_radps: np.ndarray, accel_mps2: np.ndarray,
                 opts: StillOptions = StillOptions(), gravity_mps2: float = GRAVITY_MPS2) -> float:
    """Share of back-to-back windows of ``opts.window_s`` that are not still (cheap, for long logs)."""
    dt_s = float(np.median(np.diff(stamps_ns))) / NS_PER_S
    w = max(3, int(round(opts.window_s / dt_s)))
    nb = len(stamps_ns) // w
    if nb == 0:
        return 1.0
    g = gyro_radps[: nb * w].reshape(nb, w, 3)
    a = accel_mps2[: nb * w].reshape(nb, w, 3)
    ok = _still(g.mean(axis=1), g.std(axis=1), a.mean(axis=1), a.std(axis=1), opts, gravity_mps2)
    return float(1.0 - ok.mean())


def _still(g_mean: np.ndarray, g_std: np.ndarray, a_mean: np.ndarray, a_std: np.ndarray, opts: StillOptions,
           gravity_mps2: float) -> np.ndarray:
    ok = (g_std.max(axis=1) < opts.gyro_std_max_radps) & (a_std.max(axis=1) < opts.accel_std_max_mps2)
    ok &= np.linalg.norm(g_mean, axis=1) < opts.gyro_rate_max_radps
    ok &= np.abs(np.linalg.norm(a_mean, axis=1) - gravity_mps2) < opts.accel_norm_tol_mps2
    return ok


def _moving_mean_std(x: np.ndarray, w: int) -> tuple[np.ndarray, np.ndarray]:
    """Mean and standard deviation over every window of ``w`` consecutive rows (n - w + 1 of them)."""
    mu = x.mean(axis=0)
    x = x - mu
    c1 = np.concatenate([np.zeros((1, x.shape[1])), np.cumsum(x, axis=0)])
    c2 = np.concatenate([np.zeros((1, x.shape[1])), np.cumsum(x * x, axis=0)])
    m = (c1[w:] - c1[:-w]) / w
    var = np.maximum((c2[w:] - c2[:-w]) / w - m * m, 0.0)
    return m + mu, np.sqrt(var)


def find_still_stretch(stamps_ns: np.ndarray, gyro_radps: np.ndarray, accel_mps2: np.ndarray,
                       opts: StillOptions = StillOptions(), gravity_mps2: float = GRAVITY_MPS2) -> tuple[int, int]:
    """(start_ns, end_ns) of the first still stretch that lasts ``opts.min_duration_s`` (a standing start is
    preferred: a platform cruising straight without vibration can look still to an IMU); InputError saying
    where the IMU moves if there is none."""
    stamps_ns, gyro_radps, accel_mps2 = check_imu(stamps_ns, gyro_radps, accel_mps2)
    mask = still_mask(stamps_ns, gyro_radps, accel_mps2, opts, gravity_mps2)
    trim_ns = int(opts.trim_s * NS_PER_S)
    need_ns = opts.min_duration_s * NS_PER_S
    longest = 0
    for a, b in true_runs(mask):
        s, e = int(stamps_ns[a]) + trim_ns, int(stamps_ns[b - 1]) - trim_ns
        if e - s >= need_ns:
            return s, e
        longest = max(longest, e - s)
    # a pause too short to hold the stretch joins the motion around it, so the message names the motion, not blips
    moving = time_ranges_text(stamps_ns, ~mask, int(stamps_ns[0]), join_ns=int(need_ns) + 2 * trim_ns)
    # the longest stretch rounded down, so it never reads as long as the stretch asked for
    raise InputError(f"no still stretch of {opts.min_duration_s:g} s in the IMU data: it moves during {moving} "
                     f"(s after its first stamp, pauses shorter than {opts.min_duration_s:g} s included; the longest "
                     f"still stretch lasts {math.floor(longest / NS_PER_S * 100) / 100:g} s); record a few seconds standing still or name a "
                     f"still interval")


def estimate_imu_static(stamps_ns: np.ndarray, gyro_radps: np.ndarray, accel_mps2: np.ndarray,
                        still_ns: tuple[int, int] | None = None, gravity_mps2: float = GRAVITY_MPS2,
                        opts: StillOptions = StillOptions()) -> ImuStatic:
    """Gyro bias, gravity direction, accelerometer bias along gravity and noise densities from the still
    stretch ``still_ns`` = (start_ns, end_ns), found automatically when None."""
    stamps_ns, gyro_radps, accel_mps2 = check_imu(stamps_ns, gyro_radps, accel_mps2)
    notes: list[str] = []
    if still_ns is None:
        start, end = find_still_stretch(stamps_ns, gyro_radps, accel_mps2, opts, gravity_mps2)
        notes.append(f"still stretch found at {(start - stamps_ns[0]) / NS_PER_S:.2f}-{(end - stamps_ns[0]) / NS_PER_S:.2f} s "
                     f"after the first IMU stamp")
    else:
        start, end = int(still_ns[0]), int(still_ns[1])
        if end <= start:
            raise InputError(f"still interval: its end must come after its start (got {start} .. {end} ns)")
    sel = (stamps_ns >= start) & (stamps_ns <= end)
    n = int(sel.sum())
    if n < 20:
        raise InputError(f"still interval holds {n} IMU samples (need at least 20): it lies outside the IMU data "
                         f"or is too short")
    t_s = (stamps_ns[sel] - start) / NS_PER_S
    g, a = gyro_radps[sel], accel_mps2[sel]
    dt_s = float(np.median(np.diff(stamps_ns[sel]))) / NS_PER_S
    g_mean, a_mean = g.mean(axis=0), a.mean(axis=0)
    if still_ns is not None:
        m = still_mask(stamps_ns[sel], g, a, opts, gravity_mps2)
        if m.size and m[len(m) // 4: 3 * len(m) // 4].mean() < 0.5:
            notes.append("the given still interval does not look still (the IMU turns or shakes): biases and noise "
                         "read from it are suspect")
    g_std, a_std = _detrended_std(t_s, g), _detrended_std(t_s, a)
    norm = float(np.linalg.norm(a_mean))
    up = a_mean / norm
    along_sigma = float(np.sqrt(np.sum((up * a_std) ** 2) / n))
    b_along = norm - gravity_mps2
    notes.append(f"accelerometer bias read along gravity only, against a nominal {gravity_mps2:g} m/s^2 (one attitude "
                 f"cannot separate the two; horizontal bias components look like tilt)")
    return ImuStatic(
        start_ns=start, end_ns=end, samples=n, gyro_bias_radps=g_mean, gyro_bias_sigma_radps=g_std / np.sqrt(n),
        up_imu=up, specific_force_norm_mps2=norm, gravity_mps2=float(gravity_mps2),
        accel_bias_along_gravity_mps2=float(b_along), accel_bias_along_gravity_sigma_mps2=along_sigma,
        accel_bias_mps2=b_along * up, gyro_noise_density=g_std * np.sqrt(dt_s), accel_noise_density=a_std * np.sqrt(dt_s),
        noise_density_rel_sigma=float(1.0 / np.sqrt(2.0 * (n - 2))), notes=tuple(notes),
    )


def _detrended_std(t_s: np.ndarray, x: np.ndarray) -> np.ndarray:
    """Per-column standard deviation about a straight-line fit (slow bias drift taken out)."""
    A = np.column_stack([np.ones_like(t_s), t_s - t_s.mean()])
    coef, *_ = np.linalg.lstsq(A, x, rcond=None)
    r = x - A @ coef
    return np.sqrt((r * r).sum(axis=0) / max(len(t_s) - 2, 1))
