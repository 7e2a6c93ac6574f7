"""How late each source is stamped against the IMU, measured from the data over the whole log.

The wheels' yaw rate and the odometry's (its poses' turn between messages) are compared with the gyro's base-z
rate averaged over the same instants shifted by a trial offset; the GPS fixes with a dead-reckoned track (the
wheels' or the odometry's positions, turned by the gyro's heading) at the shifted instants (``clock_lags``,
which measures every source). Each comparison
fits its own gain and bias (a complex gain and origin per window for the track: scale, heading and drift), so
only the timing is measured. The offset is the trial (coarse grids, then a parabola) that leaves the least
residual; its 1-sigma comes from a delete-one-segment jackknife over ``SEGMENTS`` stretches of the log, so slow
correlated errors (slip, multipath) count.

Convention (``imu_time_offset_s``'s): ``offset_s`` is ADDED to the source's stamps to put them on the IMU's
clock; a source stamped 0.3 s late measures -0.3.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from ..imu import running_integral

SEARCH_S = 2.0  # trial offsets within +-this
COARSE_STEP_S = 0.01
SCAN_STEP_S = 0.05  # the whole search's grid, then COARSE_STEP_S around its least (a yaw rate's cost is this smooth)
SEGMENTS = 8  # jackknife stretches
MIN_SAMPLES = 50  # rate samples (or fixes) a measurement needs
MIN_TURN_RADPS = 0.02  # the gyro's yaw rate must vary by this (std) to time a rate against it
OUTLIER_MADS = 4.0  # a residual this many robust sigmas out is a slip or a multipath fix: left out
FINE_HALF_S, FINE_STEP_S = 0.05, 0.002
SIGMA_FLOOR_S = 1e-4
GPS_TIMING_SCATTER_M = 0.5  # fixes scattered more about the track (a consumer receiver's wander) time nothing
# a yaw rate timed against the gyro must follow it: the share of its variance the fit explains (skid-steered
# wheels fall far below; docs/benchmarks.md, sources on other clocks)
MIN_EXPLAINED = 0.9
# a warning needs the offset to explain the data clearly better than none: the track's or the rate's own errors
# (a slip burst) can pull a jackknife-tight offset that hardly lowers the residual
MIN_GAIN = 1.2

Residual = Callable[[float, np.ndarray], np.ndarray]  # (trial offset, kept samples) -> every sample's residual


@dataclass
class Lag:
    """One source's measured offset (``offset_s`` added to its stamps puts it on the IMU's clock) with its 1-sigma,
    against what (``against``), or why it could not be measured (``why``; ``offset_s`` None)."""

    source: str
    offset_s: float | None
    sigma_s: float | None
    against: str
    why: str = ""
    samples: int = 0
    scatter_m: float | None = None  # GPS: the fixes' rms residual about the fitted track
    explained: float | None = None  # a yaw rate: the share of its variance the gyro's explains at the offset
    gain: float = 1.0  # the residual unshifted over that at the offset (squared sums)

    @property
    def trusted(self) -> bool:
        """Measured, and from fixes whose scatter about the track lets a timing stand out from their wander (GPS)
        or a yaw rate that follows the gyro's (``MIN_EXPLAINED``)."""
        return self.offset_s is not None and (self.scatter_m is None or self.scatter_m <= GPS_TIMING_SCATTER_M) \
            and (self.explained is None or self.explained >= MIN_EXPLAINED)

    @property
    def clear(self) -> bool:
        """Trusted, and the offset explains the data clearly better than none (``MIN_GAIN``): worth a warning."""
        return self.trusted and self.gain >= MIN_GAIN

    def to_dict(self) -> dict:
        if self.offset_s is None:
            return {"measured": False, "why": self.why}
        out = {"measured": True, "offset_s": round(self.offset_s, 4), "sigma_s": round(self.sigma_s, 4),
               "against": self.against, "samples": self.samples}
        if self.scatter_m is not None:
            out["scatter_m"] = round(self.scatter_m, 3)
            if not self.trusted:
                out["indicative"] = (f"the fixes scatter {self.scatter_m:.2f} m about the track (beyond "
                                     f"{GPS_TIMING_SCATTER_M:g} m their slow wander can pass for a timing)")
        out["gain"] = round(self.gain, 3)
        if self.explained is not None:
            out["explained"] = round(self.explained, 3)
            if self.explained < MIN_EXPLAINED:
                out["indicative"] = (f"the gyro's rate explains {self.explained:.0%} of its yaw rate's variance "
                                     f"(under {MIN_EXPLAINED:.0%}: skid, slip or noise can pass for a timing)")
        return out


class Gyro:
    """The gyro's base-z rate as a cumulative angle: the mean rate over any interval, by interpolation."""

    def __init__(self, stamps_ns: np.ndarray, rate_z: np.ndarray) -> None:
        ok = np.isfinite(rate_z)
        st, w = stamps_ns[ok], rate_z[ok]
        order = np.argsort(st, kind="stable")
        st, w = st[order], w[order]
        keep = np.concatenate([[True], np.diff(st) > 0])
        self.t0 = int(st[0]) if len(st) else 0
        self.t = (st[keep] - self.t0) * 1e-9
        w = w[keep]
        self.angle = running_integral(self.t, w) if len(w) else w

    def __len__(self) -> int:
        return len(self.t)

    def rel(self, stamps_ns: np.ndarray) -> np.ndarray:
        return (np.asarray(stamps_ns, np.int64) - self.t0) * 1e-9

    def heading(self, t: np.ndarray) -> np.ndarray:
        return np.interp(t, self.t, self.angle)

    def mean_rate(self, a: np.ndarray, b: np.ndarray) -> np.ndarray:
        return (self.heading(b) - self.heading(a)) / (b - a)

    def inside(self, a: np.ndarray, b: np.ndarray) -> np.ndarray:
        return (a - SEARCH_S >= self.t[0]) & (b + SEARCH_S <= self.t[-1])


def _segments(t: np.ndarray) -> np.ndarray:
    """The jackknife stretch of each sample: ``SEGMENTS`` equal spans of time."""
    edges = np.linspace(t.min(), t.max(), SEGMENTS + 1)
    return np.clip(np.searchsorted(edges, t, side="right") - 1, 0, SEGMENTS - 1)


def _minimum(trials: np.ndarray, cost: np.ndarray) -> float:
    """The trial of least cost, refined by a parabola through it and its neighbours."""
    k = int(np.nanargmin(cost))
    if 0 < k < len(cost) - 1:
        c0, c1, c2 = cost[k - 1], cost[k], cost[k + 1]
        den = c0 - 2 * c1 + c2
        if den > 0:
            return float(trials[k] + 0.5 * (c0 - c2) / den * (trials[1] - trials[0]))
    return float(trials[k])


def _costs(resid: Residual, seg: np.ndarray, keep: np.ndarray, trials: np.ndarray) -> np.ndarray:
    """(SEGMENTS, T) squared residuals of the kept samples per stretch at each trial offset."""
    out = np.zeros((SEGMENTS, len(trials)))
    for j, tau in enumerate(trials):
        r = resid(float(tau), keep)
        out[:, j] = np.bincount(seg[keep], np.abs(r[keep]) ** 2, SEGMENTS)
    return out


def _coarse(resid: Residual, seg: np.ndarray, keep: np.ndarray) -> float:
    """The least residual over the whole search on a ``SCAN_STEP_S`` grid, then ``COARSE_STEP_S`` around it."""
    scan = np.arange(-SEARCH_S, SEARCH_S + SCAN_STEP_S / 2, SCAN_STEP_S)
    k = int(np.nanargmin(_costs(resid, seg, keep, scan).sum(axis=0)))
    lo, hi = scan[max(k - 1, 0)], scan[min(k + 1, len(scan) - 1)]
    coarse = np.arange(lo, hi + COARSE_STEP_S / 2, COARSE_STEP_S)
    return _minimum(coarse, _costs(resid, seg, keep, coarse).sum(axis=0))


def fit_lag(resid: Residual, seg: np.ndarray) -> tuple[float, float, int, float]:
    """(offset, jackknife 1-sigma, samples kept, gain): the least residual over a coarse grid, outliers (slips,
    multipath) left out at it, then again on the coarse and a fine grid; gain, the kept samples' squared residual
    unshifted over that at the offset."""
    keep = np.ones(len(seg), bool)
    best = _coarse(resid, seg, keep)
    for _ in range(2):  # a fit pulled by outliers leaves some of them in: once more from the cleaner fit
        r = np.abs(resid(best, keep))
        keep = r <= max(OUTLIER_MADS * 1.4826 * float(np.median(r)), 1e-12)
        best = _coarse(resid, seg, keep)
    if abs(best) > SEARCH_S - 2 * COARSE_STEP_S:
        return best, float("inf"), int(np.count_nonzero(keep)), 1.0
    fine = best + np.arange(-FINE_HALF_S, FINE_HALF_S + FINE_STEP_S / 2, FINE_STEP_S)
    per = _costs(resid, seg, keep, fine)
    best = _minimum(fine, per.sum(axis=0))
    filled = [k for k in range(SEGMENTS) if np.any(keep & (seg == k))]
    held = np.array([_minimum(fine, per.sum(axis=0) - per[k]) for k in filled])
    n = len(held)
    sigma = float(np.sqrt((n - 1) / n * np.sum((held - held.mean()) ** 2))) if n > 1 else float("nan")
    cost = [float(np.sum(np.abs(resid(tau, keep)[keep]) ** 2)) for tau in (0.0, best)]
    return best, max(sigma, SIGMA_FLOOR_S), int(np.count_nonzero(keep)), cost[0] / max(cost[1], 1e-300)


def lag_of(source: str, fit: tuple[float, float, int, float], against: str) -> Lag:
    off, sig, kept, gain = fit
    if not np.isfinite(sig):
        return Lag(source, None, None, against, f"not determined: the best fit lies at the edge of the "
                                                f"+-{SEARCH_S:g} s searched (the data too noisy to time it, or the "
                                                "clocks further apart)")
    return Lag(source, off, sig, against, samples=kept, gain=gain)


def _rate_resid(gyro: Gyro, a: np.ndarray, b: np.ndarray, r: np.ndarray, v: np.ndarray | None) -> Residual:
    """Residual of ``r ~ bias + gain x gyro rate over [a, b] + trial (+ share x speed v)``, fitted on the kept
    samples (wheels of unequal radii turn in proportion to their speed, which no timing explains)."""
    def resid(tau: float, keep: np.ndarray) -> np.ndarray:
        g = gyro.mean_rate(a + tau, b + tau)
        X = g[:, None] if v is None else np.column_stack([g, v])
        mean = X[keep].mean(axis=0)
        Xc, rk = X[keep] - mean, r[keep]
        coef = np.linalg.lstsq(Xc, rk - rk.mean(), rcond=None)[0]
        return r - rk.mean() - (X - mean) @ coef
    return resid


def rate_lag(source: str, gyro: Gyro, stamps_ns: np.ndarray, rate: np.ndarray, half_ns: np.ndarray | int,
             against: str, speed: np.ndarray | None = None) -> Lag:
    """A yaw-rate source (rate over [stamp - half, stamp + half]) timed against the gyro; ``speed``: the source's
    own forward speed, a term of the fit."""
    a = gyro.rel(stamps_ns - half_ns)
    b = gyro.rel(stamps_ns + half_ns)
    ok = np.isfinite(rate) & (b > a) & gyro.inside(a, b)
    if speed is not None:
        ok &= np.isfinite(speed)
    if np.count_nonzero(ok) < MIN_SAMPLES:
        return Lag(source, None, None, against, f"fewer than {MIN_SAMPLES} {source} yaw rates inside the gyro's span")
    a, b, r = a[ok], b[ok], rate[ok]
    if float(np.std(gyro.mean_rate(a, b))) < MIN_TURN_RADPS:
        return Lag(source, None, None, against, "too little turning to time its yaw rate against the gyro")
    resid = _rate_resid(gyro, a, b, r, None if speed is None else speed[ok])
    lag = lag_of(source, fit_lag(resid, _segments(a)), against)
    if lag.offset_s is not None:  # the fit's last trim at its offset, and what the gyro's rate explains there
        e = np.abs(resid(lag.offset_s, np.ones(len(r), bool)))
        keep = e <= max(OUTLIER_MADS * 1.4826 * float(np.median(e)), 1e-12)
        e = resid(lag.offset_s, keep)[keep]
        lag.explained = float(1.0 - np.sum(e**2) / max(float(np.sum((r[keep] - r[keep].mean()) ** 2)), 1e-30))
    return lag


def _odom_rates(stamps_ns: np.ndarray, poses: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(interval start, end, base-z turn rate) between consecutive valid poses."""
    order = np.argsort(stamps_ns, kind="stable")
    st, T = stamps_ns[order], poses[order]
    ok = np.isfinite(T).all(axis=(1, 2)) & (np.abs(np.linalg.det(T[:, :3, :3]) - 1) < 1e-3)
    st, R = st[ok], T[ok, :3, :3]
    dR = np.einsum("nji,njk->nik", R[:-1], R[1:])  # R_i^T R_{i+1}
    yaw = np.arctan2(dR[:, 1, 0] - dR[:, 0, 1], dR[:, 0, 0] + dR[:, 1, 1])
    dt = np.diff(st)
    good = dt > 0
    return st[:-1][good], st[1:][good], yaw[good] / (dt[good] * 1e-9)


def odom_lag(gyro: Gyro, stamps_ns: np.ndarray, poses: np.ndarray) -> Lag:
    a_ns, b_ns, rate = _odom_rates(np.asarray(stamps_ns, np.int64), np.asarray(poses, float))
    mid = (a_ns + b_ns) // 2
    return rate_lag("odom", gyro, mid, rate, (b_ns - a_ns) // 2, "its poses' turn rate against the gyro's")


__all__ = ["Gyro", "Lag", "Residual", "fit_lag", "lag_of", "odom_lag", "rate_lag"]
