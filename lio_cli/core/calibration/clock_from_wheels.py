"""The IMU's clock offset from a ground vehicle's wheels: when does the gyro turn as the wheels say?

The wheel odometry's yaw rate ``w`` (on the LiDAR's clock: both are the base's) and the gyro ``g`` (IMU stamps +
``imu_time_offset_s`` = LiDAR clock) obey ``w(t) = a . g(t - offset) + c``: ``a`` is the base's vertical in the
IMU frame over the wheels' yaw-rate scale, ``c`` the gyro bias along it (linear in time: it drifts; a
finer model fits the turns themselves) and a share of the speed (unequal wheel radii). Linear in (a, c) for a given offset:
a coarse grid, then Brent on the residual. No mounting is needed, nor any registration: a robot whose 2D scans
time the IMU to milliseconds at best gets it to tenths where its turn rate changes. The 1-sigma is the
residuals' (sandwich over ``LAG_S`` of neighbouring samples: slip and scale errors are slow), or half the
difference between the two halves of the log timed alone where that is larger.
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np

from ...errors import InputError
from ...minimize import minimize_bounded
from ..robust import robust_sigma
from .common import NS_PER_S, CalibrationResult, sandwich_covariance
from .signals import PiecewiseLinear
from .time_offset import TimeOffset

COARSE_STEP_S = 0.005
# the gyro is averaged over a hat of this half-width: interpolated raw samples are noisier at the samples than
# between them, which makes the residual ripple with the IMU's sampling period
SMOOTH_S = 0.04
LAG_S = 0.5  # neighbouring samples whose errors may be shared
MIN_SAMPLES = 100
MIN_EXPLAINED = 0.8  # share of the wheels' yaw-rate variance the gyro must explain: else not the same motion
OUTLIER_SIGMAS = 4.0
TRIM = 0.8  # the share of samples the first fits keep (the best-fitting ones)
AGREE_SIGMAS = 3.0  # the LiDAR's and the wheels' offsets further apart: the wheels keep another clock
HINT = "turn with a changing rate (start and stop turns, a slalom)"


@dataclass(frozen=True, eq=False)
class WheelClock(CalibrationResult):
    imu_time_offset_s: float  # t_lidar = t_imu_stamp + offset
    sigma_s: float
    axis_imu: np.ndarray  # (3,) the base's vertical in the IMU frame (unit)
    scale: float  # |a|: the gyro's turn rate over the wheels'
    samples: int
    explained: float  # share of the wheels' yaw-rate variance the fit explains
    rms_residual_radps: float
    notes: tuple[str, ...]


def estimate_clock_from_wheels(wheel_stamps_ns: np.ndarray, yaw_rate_radps: np.ndarray, imu_stamps_ns: np.ndarray,
                               gyro_radps: np.ndarray, *, speed_mps: np.ndarray | None = None, centre_s: float = 0.0,
                               max_offset_s: float = 0.5, max_sigma_s: float = 0.002) -> WheelClock:
    """Clock offset of the IMU from the wheels' yaw rate (see the module). ``speed_mps``: the wheels' forward
    speed, whose share of their yaw rate (unequal wheel radii) is fitted too. The search spans ``centre_s`` +-
    ``max_offset_s``; InputError when the motion cannot time it (1-sigma above ``max_sigma_s``), when the best
    offset is at the search's edge, or when the gyro does not explain the wheels' turns."""
    ws = np.asarray(wheel_stamps_ns, np.int64)
    w = np.asarray(yaw_rate_radps, float)
    v = np.zeros(len(w)) if speed_mps is None else np.asarray(speed_mps, float)
    it = np.asarray(imu_stamps_ns, np.int64)
    t0 = int(it[0])
    ti, tw = (it - t0) / NS_PER_S, (ws - t0) / NS_PER_S
    lo, hi = centre_s - max_offset_s, centre_s + max_offset_s
    inside = (tw - hi - SMOOTH_S >= ti[0]) & (tw - lo + SMOOTH_S <= ti[-1]) & np.isfinite(w) & np.isfinite(v)
    tw, w, v = tw[inside], w[inside], v[inside]
    if len(tw) < MIN_SAMPLES:
        raise InputError(f"clock offset from the wheels: {len(tw)} wheel samples overlap the IMU (need {MIN_SAMPLES})")
    if float(np.std(w)) < np.radians(1.0):
        raise InputError(f"clock offset from the wheels: the wheels' turn rate hardly changes (std "
                         f"{np.degrees(np.std(w)):.2f} deg/s): {HINT}")
    g = np.asarray(gyro_radps, float)
    # the axis the gyro turns most about is the base's vertical (a free 3-vector would fit the bias-only
    # horizontal axes to the wheels' slip)
    axis = np.linalg.eigh(np.cov(g.T))[1][:, -1]
    yaw = PiecewiseLinear(ti, g @ axis)
    extra = [np.ones(len(tw)), tw - tw.mean()] + ([v] if speed_mps is not None and np.std(v) > 0 else [])

    def design(off: float) -> np.ndarray:  # the gyro averaged over +-SMOOTH_S (a hat: no lag, no sampling phase)
        t = tw - off
        return np.column_stack([yaw.hat_average(t - SMOOTH_S, t, t + SMOOTH_S), *extra])

    def trimmed(off: float, keep: np.ndarray | None) -> tuple[float, np.ndarray, np.ndarray]:
        """(cost, fit, residuals of all samples): with ``keep`` None the least squares over the TRIM share of
        samples it fits best (slip bursts would drag a plain fit), else over ``keep``."""
        X = design(off)
        sel = np.ones(len(tw), bool) if keep is None else keep
        for _ in range(1 if keep is not None else 3):
            x = np.linalg.lstsq(X[sel], w[sel], rcond=None)[0]
            r = w - X @ x
            if keep is None:
                sel = np.abs(r) <= np.quantile(np.abs(r), TRIM)
        return float((r[sel] ** 2).sum()), x, r

    grid = np.arange(lo, hi + 0.5 * COARSE_STEP_S, COARSE_STEP_S)
    keep = None
    for attempt in range(3):  # then leave out what the gyro does not explain (slip, a bump) and fit again
        k = int(np.argmin([trimmed(d, keep)[0] for d in grid]))
        if k in (0, len(grid) - 1):
            raise InputError(f"clock offset from the wheels: the best offset lies at the edge of the +-"
                             f"{max_offset_s:g} s searched")
        off, _ = minimize_bounded(lambda d: trimmed(d, keep)[0], grid[k] - COARSE_STEP_S, grid[k] + COARSE_STEP_S,
                                  xatol=1e-6)
        _, x, r = trimmed(off, keep)
        inl = np.abs(r) <= np.quantile(np.abs(r), TRIM) if keep is None else keep
        mad = robust_sigma(r[inl], centre=False)
        new = np.abs(r) <= OUTLIER_SIGMAS * max(mad, 1e-6)
        if keep is not None and (new == keep).all():
            break
        keep = new
    _, x, r = trimmed(off, keep)
    X = design(off)
    r, n = r[keep], int(keep.sum())
    explained = 1.0 - float(r @ r) / float(((w[keep] - w[keep].mean()) ** 2).sum())
    if explained < MIN_EXPLAINED:
        raise InputError(f"clock offset from the wheels: the gyro explains {100 * explained:.0f}% of the wheels' "
                         f"turn rate (need {100 * MIN_EXPLAINED:.0f}%): slipping wheels, or another vehicle's odometry?")
    h = 1e-4
    J = np.column_stack([-(design(off + h) - design(off - h))[:, 0] * x[0] / (2 * h), X])[keep]
    dt = float(np.median(np.diff(tw)))
    cov = sandwich_covariance(J.T @ J, J * r[:, None], lag=max(1, int(round(LAG_S / dt))))
    sigma = float(np.sqrt(max(cov[0, 0], 0.0)))
    # each half of the log on its own: their disagreement shows errors the residuals' correlation does not
    halves = []
    for part in (tw < np.median(tw[keep]), tw >= np.median(tw[keep])):
        sel = keep & part
        halves.append(minimize_bounded(lambda d: trimmed(d, sel)[0], off - 5 * COARSE_STEP_S, off + 5 * COARSE_STEP_S,
                                       xatol=1e-6)[0])
    sigma = max(sigma, abs(halves[1] - halves[0]) / 2)
    if sigma > max_sigma_s:
        raise InputError(f"clock offset from the wheels: too little change in the turn rate (1-sigma "
                         f"{1e3 * sigma:.1f} ms): {HINT}")
    notes = () if n == len(tw) else (f"{len(tw) - n} wheel samples the gyro does not explain left out (slip?)",)
    return WheelClock(float(off), sigma, axis * np.sign(x[0]), float(abs(x[0])), n, explained,
                      float(np.sqrt((r * r).mean())), notes)


def with_wheel_clock(lidar: TimeOffset, wheels: WheelClock) -> TimeOffset:
    """The clock offset from both sources: the wheels' where the LiDAR's rotations could not time the IMU; the
    inverse-variance mean where both agree within ``AGREE_SIGMAS``; else the LiDAR's, with a note (the wheel
    odometry is taken to share the LiDAR's clock, and here it does not seem to)."""
    s_w = wheels.sigma_s
    said = (f"the clock offset from the wheels' turn rate against the gyro's: {1e3 * wheels.imu_time_offset_s:+.3f} "
            f"ms, 1-sigma {1e3 * s_w:.3f} ms ({wheels.samples} samples)")
    if not np.isfinite(lidar.sigma_s):
        return replace(lidar, imu_time_offset_s=wheels.imu_time_offset_s, sigma_s=s_w,
                       notes=(f"{said}; the LiDAR's rotations could not time the IMU ({lidar.notes[0]})",))
    d = wheels.imu_time_offset_s - lidar.imu_time_offset_s
    both = float(np.hypot(lidar.sigma_s, s_w))
    if abs(d) > AGREE_SIGMAS * both:
        return replace(lidar, notes=(*lidar.notes, f"{said} disagrees with the LiDAR's by {1e3 * d:+.2f} ms (1-sigma "
                                     f"{1e3 * both:.2f}): the wheel odometry seems to keep another clock; not used"))
    wl, ww = 1.0 / lidar.sigma_s**2, 1.0 / s_w**2
    off = (wl * lidar.imu_time_offset_s + ww * wheels.imu_time_offset_s) / (wl + ww)
    return replace(lidar, imu_time_offset_s=float(off), sigma_s=float(1.0 / np.sqrt(wl + ww)),
                   notes=(*lidar.notes, f"{said}; combined with the LiDAR's ({1e3 * lidar.imu_time_offset_s:+.3f} "
                          f"ms, 1-sigma {1e3 * lidar.sigma_s:.3f} ms)"))
