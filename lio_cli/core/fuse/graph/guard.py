"""Never worse than the filter: the smoothed keyframes against the filter's, by what the measurements say.

Per source, the RMS of its residuals at the keyframes: GPS horizontal (each clipped at ``CLIP`` sigmas, so an
outlier weighs the same for both; the mean residual of each 5 s window of fixes apart, ``gps_slow_m``, judged
against that error's own sigma), odometry and wheel increments (translation). The smoothed
solution is refused when one source's RMS exceeds the filter's by more than ``RATIO`` plus that source's floor
*and* the RMS its own sigmas predict (``noise_levels``, times ``NOISE_MARGIN``): a filter that jumps to every
odometry pose or GPS fix sits closer to them than their noise, a smoother need not. Beside odometry GPS's
residuals may be worse by more (``ratios``): there the filter follows a consumer receiver's wander.
"""

from __future__ import annotations

import numpy as np

from ..inputs import at_antenna
from .factors import Measurements

RATIO = 1.05  # worse than the filter only beyond this: a good smoother's residual sits near the filter's
GPS_BESIDE_ODOM_RATIO = 1.5  # GPS's, beside odometry (``ratios``)
CLIP = 3.0
NOISE_MARGIN = 1.05  # worse only beyond both the filter's residual and the sigmas' own prediction, by this
FLOORS = {"gps_horizontal_m": 0.02, "gps_slow_m": 0.05, "odom_increment_m": 0.005, "wheel_increment_m": 0.002}


def residuals(m: Measurements, s: dict[str, np.ndarray]) -> dict[str, float]:
    """RMS residual per source of the keyframe states ``s`` (R, p, v)."""
    out: dict[str, float] = {}
    if len(m.gps_k):
        d = at_antenna(s["R"][m.gps_k], s["p"][m.gps_k], m.gps_lever)[:, :2] - m.gps_z[:, :2]
        if m.gps_bias_sigma > 0:  # the slow receiver error apart: each 5 s window's mean residual, the rest
            j, inv = np.unique(m.gps_j, return_inverse=True)
            mean = np.stack([np.bincount(inv, d[:, c]) for c in range(2)], 1) / np.bincount(inv)[:, None]
            slow = np.minimum(np.linalg.norm(mean, axis=1), CLIP * m.gps_bias_sigma)
            out["gps_slow_m"] = float(np.sqrt(np.mean(slow**2)))
            d = d - mean[inv]
        e = np.minimum(np.linalg.norm(d, axis=1), CLIP * m.gps_h)
        out["gps_horizontal_m"] = float(np.sqrt(np.mean(e**2)))
    if len(m.odom_k) > 1:
        od = m.prep.odom
        ka, kb = m.odom_k[:-1], m.odom_k[1:]
        Pa, Pb = od.poses[m.odom_idx[:-1]], od.poses[m.odom_idx[1:]]
        meas = np.einsum("nji,nj->ni", Pa[:, :3, :3], Pb[:, :3, 3] - Pa[:, :3, 3])
        est = np.einsum("nji,nj->ni", s["R"][ka], s["p"][kb] - s["p"][ka])
        ok = kb != ka
        if ok.any():
            out["odom_increment_m"] = float(np.sqrt(np.mean(np.sum((est - meas)[ok] ** 2, axis=1))))
    if m.wheel_dp:
        k = np.fromiter(m.wheel_dp, np.int64)
        dp = np.array([m.wheel_dp[i][0] for i in k.tolist()])
        est = np.einsum("nji,nj->ni", s["R"][k], s["p"][k + 1] - s["p"][k])
        out["wheel_increment_m"] = float(np.sqrt(np.mean(np.sum((est - dp) ** 2, axis=1))))
    return out


def noise_levels(m: Measurements) -> dict[str, float]:
    """The RMS residual per source that its sigmas predict (the keys of ``residuals``)."""
    out: dict[str, float] = {}
    if len(m.gps_k):
        out["gps_horizontal_m"] = float(np.sqrt(np.mean(2.0 * m.gps_h**2)))
        if m.gps_bias_sigma > 0:
            out["gps_slow_m"] = float(np.sqrt(2.0) * m.gps_bias_sigma)
    if len(m.odom_k) > 1:
        ps = m.prep.odom.position_sigma_m[m.odom_idx]
        out["odom_increment_m"] = float(np.sqrt(np.mean(3.0 * (ps[:-1] ** 2 + ps[1:] ** 2))))
    if m.wheel_dp:
        out["wheel_increment_m"] = float(np.sqrt(np.mean([np.sum(sd**2) for _, sd in m.wheel_dp.values()])))
    return out


def ratios(m: Measurements) -> dict[str, float]:
    """Per residual, how much worse than the filter's the guard lets it be: beside odometry GPS's by
    ``GPS_BESIDE_ODOM_RATIO`` (a filter that follows the fixes sits closer to a consumer receiver's wander than a
    smoother held to the odometry's shape; odometry that lost track still moves them by far more)."""
    out = dict.fromkeys(FLOORS, RATIO)
    if len(m.odom_k) > 1:
        out.update(gps_horizontal_m=GPS_BESIDE_ODOM_RATIO, gps_slow_m=GPS_BESIDE_ODOM_RATIO)
    return out


def verdict(filtered: dict[str, float], smoothed: dict[str, float], noise: dict[str, float] | None = None,
            ratio: dict[str, float] | None = None) -> str | None:
    """Why the smoothed solution is worse than the filter's (and than its sigmas predict), or None; ``ratio``
    per residual (``RATIO`` without it)."""
    noise, ratio = noise or {}, ratio or {}
    for name, f in filtered.items():
        sm = smoothed.get(name, f)
        if sm > max(ratio.get(name, RATIO) * f + FLOORS[name], NOISE_MARGIN * noise.get(name, 0.0)):
            return f"{name.rsplit('_', 1)[0].replace('_', ' ')} residual {sm:.3g} vs the filter's {f:.3g}"
    return None
