"""How late each source is stamped against the IMU, measured from the data over the whole log.

The wheels' yaw rate and the odometry's (its poses' turn between messages) are compared with the gyro's base-z
rate averaged over the same instants shifted by a trial offset; the GPS fixes with a dead-reckoned track (the
wheels' or the odometry's positions, turned by the gyro's heading) at the shifted instants. Each comparison
fits its own gain and bias (a complex gain and origin per window for the track: scale, heading and drift), so
only the timing is measured. The offset is the trial (coarse grid, then a parabola) that leaves the least
residual; its 1-sigma comes from a delete-one-segment jackknife over ``SEGMENTS`` stretches of the log, so slow
correlated errors (slip, multipath) count.

Convention (``imu_time_offset_s``'s): ``offset_s`` is ADDED to the source's stamps to put them on the IMU's
clock; a source stamped 0.3 s late measures -0.3.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from .inputs import FuseInputs

SEARCH_S = 2.0  # trial offsets within +-this
COARSE_STEP_S = 0.01
SEGMENTS = 8  # jackknife stretches
MIN_SAMPLES = 50  # rate samples (or fixes) a measurement needs
MIN_TURN_RADPS = 0.02  # the gyro's yaw rate must vary by this (std) to time a rate against it
GPS_WINDOW_S = 10.0  # the track's scale, heading, origin and drift fitted anew per window (the jackknife's stretch)
MIN_GPS_SPAN_M = 5.0  # the fixes must travel this far to time them
OUTLIER_MADS = 4.0  # a residual this many robust sigmas out is a slip or a multipath fix: left out
FINE_HALF_S, FINE_STEP_S = 0.05, 0.002
SIGMA_FLOOR_S = 1e-4
GPS_TIMING_SCATTER_M = 0.5  # simulated: RTK fixes scatter 0.03-0.22 m about the track, consumer ones 1.7-1.9 m

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

    @property
    def trusted(self) -> bool:
        """Measured, and (GPS) from fixes whose scatter about the track lets a timing stand out from their wander."""
        return self.offset_s is not None and (self.scatter_m is None or self.scatter_m <= GPS_TIMING_SCATTER_M)

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
        return out


class _Gyro:
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
        self.angle = np.concatenate([[0.0], np.cumsum(0.5 * (w[1:] + w[:-1]) * np.diff(self.t))]) if len(w) else w

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


def _fit(resid: Residual, seg: np.ndarray) -> tuple[float, float, int]:
    """(offset, jackknife 1-sigma, samples kept): the least residual over a coarse grid, outliers (slips,
    multipath) left out at it, then again on the coarse and a fine grid."""
    keep = np.ones(len(seg), bool)
    coarse = np.arange(-SEARCH_S, SEARCH_S + COARSE_STEP_S / 2, COARSE_STEP_S)
    best = _minimum(coarse, _costs(resid, seg, keep, coarse).sum(axis=0))
    for _ in range(2):  # a fit pulled by outliers leaves some of them in: once more from the cleaner fit
        r = np.abs(resid(best, keep))
        keep = r <= max(OUTLIER_MADS * 1.4826 * float(np.median(r)), 1e-12)
        best = _minimum(coarse, _costs(resid, seg, keep, coarse).sum(axis=0))
    if abs(best) > SEARCH_S - 2 * COARSE_STEP_S:
        return best, float("inf"), int(np.count_nonzero(keep))
    fine = best + np.arange(-FINE_HALF_S, FINE_HALF_S + FINE_STEP_S / 2, FINE_STEP_S)
    per = _costs(resid, seg, keep, fine)
    best = _minimum(fine, per.sum(axis=0))
    filled = [k for k in range(SEGMENTS) if np.any(keep & (seg == k))]
    held = np.array([_minimum(fine, per.sum(axis=0) - per[k]) for k in filled])
    n = len(held)
    sigma = float(np.sqrt((n - 1) / n * np.sum((held - held.mean()) ** 2))) if n > 1 else float("nan")
    return best, max(sigma, SIGMA_FLOOR_S), int(np.count_nonzero(keep))


def _lag(source: str, fit: tuple[float, float, int], against: str) -> Lag:
    off, sig, kept = fit
    if not np.isfinite(sig):
        return Lag(source, None, None, against, f"not determined: the best fit lies at the edge of the +-{SEARCH_S:g} s "
                                                "searched (the data too noisy to time it, or the clocks further apart)")
    return Lag(source, off, sig, against, samples=kept)


def _rate_resid(gyro: _Gyro, a: np.ndarray, b: np.ndarray, r: np.ndarray, v: np.ndarray | None) -> Residual:
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


def rate_lag(source: str, gyro: _Gyro, stamps_ns: np.ndarray, rate: np.ndarray, half_ns: np.ndarray | int,
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
    return _lag(source, _fit(_rate_resid(gyro, a, b, r, None if speed is None else speed[ok]), _segments(a)), against)


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


def odom_lag(gyro: _Gyro, stamps_ns: np.ndarray, poses: np.ndarray) -> Lag:
    a_ns, b_ns, rate = _odom_rates(np.asarray(stamps_ns, np.int64), np.asarray(poses, float))
    mid = (a_ns + b_ns) // 2
    return rate_lag("odom", gyro, mid, rate, (b_ns - a_ns) // 2, "its poses' turn rate against the gyro's")


def _track_resid(track_t: np.ndarray, track_xy: np.ndarray, t: np.ndarray, z: np.ndarray, win: np.ndarray,
                 heading: Callable, antenna: complex | None) -> Residual:
    """Residual of fixes ``z`` (complex east + i north) against the track (complex) at ``t + trial`` after a complex
    gain (scale and heading), origin and drift per window (the receiver's slow error), fitted on the kept fixes."""
    nwin = int(win.max()) + 1
    rows = [np.flatnonzero(win == k) for k in range(nwin)]

    def resid(tau: float, keep: np.ndarray) -> np.ndarray:
        tt = t + tau
        p = np.interp(tt, track_t, track_xy.real) + 1j * np.interp(tt, track_t, track_xy.imag)
        if antenna is not None:
            p = p + antenna * np.exp(1j * heading(tt))
        out = np.zeros_like(z)
        for idx in rows:
            k = idx[keep[idx]]
            if len(k) < 4:
                continue
            tc = t[idx] - t[k].mean()
            A = np.column_stack([p[idx], np.ones(len(idx)), tc])
            x = np.linalg.lstsq(A[keep[idx]], z[k], rcond=None)[0]
            out[idx] = z[idx] - A @ x
        return out
    return resid


def gps_lag(gyro: _Gyro, inputs: FuseInputs, shifts: dict[str, float]) -> Lag:
    """The fixes against the wheels' dead-reckoned track (their speed turned by the gyro's heading), else the
    odometry's positions; each on the IMU's clock by the offset measured for it (``shifts``, s)."""
    g = inputs.gps
    if inputs.wheel is not None and len(inputs.wheel) and np.isfinite(inputs.wheel.velocity_mps[:, 0]).any():
        w = inputs.wheel
        order = np.argsort(w.stamps_ns, kind="stable")
        st, v = w.stamps_ns[order], np.nan_to_num(w.velocity_mps[order, :2])
        t = gyro.rel(st) + shifts.get("wheel", 0.0)
        keep = np.concatenate([[True], np.diff(t) > 0])
        t, v = t[keep], v[keep]
        vw = (v[:, 0] + 1j * v[:, 1]) * np.exp(1j * gyro.heading(t))
        xy = np.concatenate([[0], np.cumsum(0.5 * (vw[1:] + vw[:-1]) * np.diff(t))])
        against, heading = "the wheels' track turned by the gyro" + (
            ", their measured lag taken out" if shifts.get("wheel") else ""), gyro.heading
    elif inputs.odom is not None and len(inputs.odom):
        o = inputs.odom
        order = np.argsort(o.stamps_ns, kind="stable")
        st, P = o.stamps_ns[order], o.poses[order]
        ok = np.isfinite(P).all(axis=(1, 2))
        t, P = gyro.rel(st[ok]) + shifts.get("odom", 0.0), P[ok]
        keep = np.concatenate([[True], np.diff(t) > 0])
        t, P = t[keep], P[keep]
        xy = P[:, 0, 3] + 1j * P[:, 1, 3]
        yaw = np.unwrap(np.arctan2(P[:, 1, 0], P[:, 0, 0]))
        against, heading = "the odometry's positions", (lambda tt: np.interp(tt, t, yaw))
    else:
        return Lag("gps", None, None, "", "no wheel odometry or odometry track to time it against")
    tg = gyro.rel(g.stamps_ns)
    ok = np.isfinite(g.position_enu_m[:, :2]).all(axis=1) & (tg - SEARCH_S >= t[0]) & (tg + SEARCH_S <= t[-1])
    if g.valid is not None:
        ok &= g.valid
    if np.count_nonzero(ok) < MIN_SAMPLES:
        return Lag("gps", None, None, against, f"fewer than {MIN_SAMPLES} fixes inside the track's span")
    tg, z = tg[ok], g.position_enu_m[ok, 0] + 1j * g.position_enu_m[ok, 1]
    if float(np.abs(z - z.mean()).max()) < MIN_GPS_SPAN_M:
        return Lag("gps", None, None, against, f"the fixes move less than {MIN_GPS_SPAN_M:g} m")
    lever = g.lever
    antenna = None if lever is None else complex(lever[0], lever[1])
    win = ((tg - tg[0]) // GPS_WINDOW_S).astype(int)
    resid = _track_resid(t, xy, tg, z, win, heading, antenna)
    off, sig, kept = fit = _fit(resid, (win * SEGMENTS) // (int(win.max()) + 1))  # windows in equal groups
    if np.isfinite(sig):  # a floor: the fixes' scatter over the track's speed, one independent error per window
        keep = np.ones(len(z), bool)
        r = np.abs(resid(off, keep))
        r = r[r <= OUTLIER_MADS * 1.4826 * float(np.median(r))]
        speed = np.abs(np.diff(xy)) / np.diff(t)
        floor = float(np.sqrt(np.mean(r**2)) / max(float(np.sqrt(np.mean(speed**2))), 1e-3) / np.sqrt(win.max() + 1))
        lag = _lag("gps", (off, max(sig, floor), kept), against)
        lag.scatter_m = float(np.sqrt(np.mean(r**2)))
        return lag
    return _lag("gps", fit, against)


def measure_lags(inputs: FuseInputs) -> dict[str, Lag]:
    """Each non-IMU source's offset against the IMU's gyro (see the module docstring); empty without a gyro."""
    imu = inputs.imu
    if imu is None or len(imu) < MIN_SAMPLES:
        return {}
    w_b = np.asarray(imu.gyro_radps, float) @ np.asarray(imu.T_base_imu)[:3, :3].T
    gyro = _Gyro(np.asarray(imu.stamps_ns, np.int64), w_b[:, 2])
    if len(gyro) < MIN_SAMPLES:
        return {}
    out: dict[str, Lag] = {}
    if inputs.wheel is not None and len(inputs.wheel):
        w = inputs.wheel
        st = np.asarray(w.stamps_ns, np.int64)
        period = int(np.median(np.diff(np.sort(st)))) if len(st) > 1 else 0
        out["wheel"] = rate_lag("wheel", gyro, st, np.asarray(w.yaw_rate_radps, float), max(period // 2, 1),
                                "its yaw rate against the gyro's", np.asarray(w.velocity_mps[:, 0], float))
    if inputs.odom is not None and len(inputs.odom) > 1:
        out["odom"] = odom_lag(gyro, inputs.odom.stamps_ns, inputs.odom.poses)
    if inputs.gps is not None and len(inputs.gps):
        shifts = {s: lag.offset_s for s, lag in out.items() if lag.trusted and abs(lag.offset_s) > 4 * lag.sigma_s}
        out["gps"] = gps_lag(gyro, inputs, shifts)
    return out


__all__ = ["Lag", "measure_lags"]
