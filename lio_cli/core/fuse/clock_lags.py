"""Each source's lag against the IMU's gyro (``clock_lag``: the method, the yaw rates'), and the GPS's: its fixes
against a dead-reckoned track (the wheels' speed turned by the gyro's heading, else the odometry's positions) at
the shifted instants, a complex gain (scale, heading), origin and drift fitted per window (the receiver's slow
error), so only the timing is measured."""

from __future__ import annotations

from collections.abc import Callable

import numpy as np

from .clock_lag import (MIN_SAMPLES, OUTLIER_MADS, SEARCH_S, SEGMENTS, Gyro, Lag, Residual, fit_lag, lag_of,
                        odom_lag, rate_lag)
from .inputs import FuseInputs

GPS_WINDOW_S = 10.0  # the track's scale, heading, origin and drift fitted anew per window (the jackknife's stretch)
MIN_GPS_SPAN_M = 5.0  # the fixes must travel this far to time them


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


def gps_lag(gyro: Gyro, inputs: FuseInputs, shifts: dict[str, float]) -> Lag:
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
    off, sig, kept, gain = fit = fit_lag(resid, (win * SEGMENTS) // (int(win.max()) + 1))  # windows in equal groups
    if np.isfinite(sig):  # a floor: the fixes' scatter over the track's speed, one independent error per window
        keep = np.ones(len(z), bool)
        r = np.abs(resid(off, keep))
        r = r[r <= OUTLIER_MADS * 1.4826 * float(np.median(r))]
        speed = np.abs(np.diff(xy)) / np.diff(t)
        floor = float(np.sqrt(np.mean(r**2)) / max(float(np.sqrt(np.mean(speed**2))), 1e-3) / np.sqrt(win.max() + 1))
        lag = lag_of("gps", (off, max(sig, floor), kept, gain), against)
        lag.scatter_m = float(np.sqrt(np.mean(r**2)))
        return lag
    return lag_of("gps", fit, against)


def measure_lags(inputs: FuseInputs) -> dict[str, Lag]:
    """Each non-IMU source's offset against the IMU's gyro (see the module docstring); empty without a gyro."""
    imu = inputs.imu
    if imu is None or len(imu) < MIN_SAMPLES:
        return {}
    w_b = np.asarray(imu.gyro_radps, float) @ np.asarray(imu.T_base_imu)[:3, :3].T
    gyro = Gyro(np.asarray(imu.stamps_ns, np.int64), w_b[:, 2])
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


__all__ = ["gps_lag", "measure_lags"]
