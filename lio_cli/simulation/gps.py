"""A GPS receiver (sensor_msgs/NavSatFix) on the simulated platform.

The world frame is ENU (x east, y north, z up) about a geodetic origin; each fix is the antenna's true
position (base pose plus the antenna lever arm) plus an error, converted to WGS84 latitude, longitude and
ellipsoidal height. The error of each axis is half white noise and half a first-order Gauss-Markov process
(correlation time ``tau_s``), so it wanders like a real receiver's while its variance is exactly the
reported covariance. Some fixes are invalid (status -1, NaN position), the receiver loses lock before and
after an outage during which it publishes nothing.

A consumer receiver (``GpsSpec.model == "consumer"``) adds what such units really do: an error that is mostly
slow (90 % of its variance Gauss-Markov with a 60 s correlation time), an altitude that wanders slowly by
``alt_wander_m`` peak to peak over the run, a multipath jump (every fix in a window ``jump_s`` long shifted
``jump_m`` horizontally) and a covariance that is optimistic (``covariance="optimistic"``: a third of the true
sigmas, the vertical wander left out) or absent (type 0, zeros).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from .motion import Trajectory
from .options import DEFAULT_GPS_ORIGIN
from .sensors import NS
from ..geodesy import EnuFrame

STATUS_FIX, STATUS_NO_FIX = 0, -1
COVARIANCE_TYPE_UNKNOWN, COVARIANCE_TYPE_DIAGONAL_KNOWN = 0, 2
OPTIMISTIC_FACTOR = 1.0 / 3.0  # reported sigma / true sigma of an optimistic receiver
# options.GPS_MODELS -> (noise_m, correlated share, tau_s, alt_wander_m, jump_m, covariance)
MODEL_DEFAULTS = {"standard": ((1.0, 2.0), 0.5, 30.0, 0.0, 0.0, "true"),
                  "consumer": ((2.5, 1.5), 0.9, 60.0, 25.0, 8.0, "optimistic")}


@dataclass
class GpsSpec:
    """``noise_m``: 1-sigma error (east and north each, up); ``outage_start_s``/``outage_s``: no messages in
    that window (seconds after the run's start); ``invalid_fraction``: share of fixes without a solution."""

    rate_hz: float = 5.0
    origin: tuple[float, float, float] = DEFAULT_GPS_ORIGIN
    noise_m: tuple[float, float] = (1.0, 2.0)
    correlated_share: float = 0.5  # of the error variance, in the Gauss-Markov part
    tau_s: float = 30.0
    invalid_fraction: float = 0.02
    outage_start_s: float = 0.0
    outage_s: float = 0.0
    antenna_m: tuple[float, float, float] = (0.0, 0.0, 0.3)
    model: str = "standard"
    alt_wander_m: float = 0.0  # peak to peak over the run, added to the up error
    jump_m: float = 0.0  # multipath: horizontal shift of every fix in [jump_start_s, jump_start_s + jump_s)
    jump_start_s: float = 0.0
    jump_s: float = 0.0
    covariance: str = "true"  # what the messages report: true, optimistic or absent


@dataclass
class GpsFixes:
    stamps_ns: np.ndarray  # (N,) header stamps (GPS time = true time)
    lat_deg: np.ndarray  # (N,) NaN where invalid
    lon_deg: np.ndarray
    alt_m: np.ndarray
    status: np.ndarray  # (N,) int8: 0 fix, -1 no fix
    antenna_enu_m: np.ndarray  # (N,3) true antenna position in world (ENU)
    error_enu_m: np.ndarray  # (N,3) the error added to it (valid fixes)
    covariance_enu_m2: np.ndarray = field(default_factory=lambda: np.zeros(3))  # reported diagonal (E, N, U)
    covariance_type: int = COVARIANCE_TYPE_DIAGONAL_KNOWN
    wander_m: np.ndarray | None = None  # (N,) the altitude wander part of error_enu_m[:, 2]
    jump_enu_m: np.ndarray | None = None  # (3,) the multipath shift inside the jump window


def gauss_markov(n: int, dt_s: float, sigma: np.ndarray, tau_s: float, rng: np.random.Generator) -> np.ndarray:
    """(n, len(sigma)) stationary first-order Gauss-Markov samples: x_k = phi x_{k-1} + sqrt(1 - phi^2) sigma w_k."""
    sigma = np.asarray(sigma, float)
    phi = float(np.exp(-dt_s / tau_s))
    w = rng.normal(0.0, 1.0, (n, len(sigma)))
    x = np.empty_like(w)
    x[0] = w[0]
    gain = np.sqrt(1.0 - phi * phi)
    for k in range(1, n):
        x[k] = phi * x[k - 1] + gain * w[k]
    return x * sigma


def gps_fixes(traj: Trajectory, spec: GpsSpec, start_ns: int, end_ns: int, traj_start_ns: int,
              rng: np.random.Generator) -> GpsFixes:
    """Fixes on a regular grid from ``start_ns`` to ``end_ns`` (inclusive), minus the outage window."""
    period_ns = int(round(NS / spec.rate_hz))
    stamps = np.arange(start_ns, end_ns + 1, period_ns, dtype=np.int64)
    st = traj.state((stamps - traj_start_ns) * 1e-9)
    antenna = st.position_m + st.R_world_base @ np.asarray(spec.antenna_m, float)
    sig = np.array([spec.noise_m[0], spec.noise_m[0], spec.noise_m[1]], float)
    share = spec.correlated_share
    err = (gauss_markov(len(stamps), period_ns * 1e-9, sig * np.sqrt(share), spec.tau_s, rng)
           + rng.normal(0.0, 1.0, (len(stamps), 3)) * sig * np.sqrt(1.0 - share))
    invalid = rng.random(len(stamps)) < spec.invalid_fraction
    wander = jump = None
    t_s = (stamps - start_ns) * 1e-9
    if spec.alt_wander_m > 0:
        wander = altitude_wander(t_s, spec.alt_wander_m, rng)
        err[:, 2] += wander
    if spec.jump_m > 0 and spec.jump_s > 0:
        heading = rng.uniform(0.0, 2.0 * np.pi)
        jump = spec.jump_m * np.array([np.cos(heading), np.sin(heading), 0.0])
        err[(t_s >= spec.jump_start_s) & (t_s < spec.jump_start_s + spec.jump_s)] += jump
    keep = np.ones(len(stamps), bool)
    if spec.outage_s > 0:
        t0 = start_ns + int(round(spec.outage_start_s * NS))
        t1 = t0 + int(round(spec.outage_s * NS))
        inside = (stamps >= t0) & (stamps < t1)
        keep &= ~inside
        before, after = np.flatnonzero(stamps < t0), np.flatnonzero(stamps >= t1)
        if len(before):
            invalid[before[-1]] = True  # the receiver loses lock ...
        if len(after):
            invalid[after[0]] = True  # ... and needs one more epoch to get it back
    lat, lon, alt = EnuFrame(*spec.origin).to_geodetic(antenna + err)
    lat, lon, alt = (np.where(invalid, np.nan, v) for v in (lat, lon, alt))
    status = np.where(invalid, STATUS_NO_FIX, STATUS_FIX).astype(np.int8)
    cov, cov_type = sig * sig, COVARIANCE_TYPE_DIAGONAL_KNOWN
    if spec.covariance == "optimistic":
        cov = cov * OPTIMISTIC_FACTOR**2
    elif spec.covariance == "absent":
        cov, cov_type = np.zeros(3), COVARIANCE_TYPE_UNKNOWN
    return GpsFixes(stamps[keep], lat[keep], lon[keep], alt[keep], status[keep], antenna[keep],
                    np.where(invalid[:, None], 0.0, err)[keep], cov, cov_type,
                    None if wander is None else wander[keep], jump)


def altitude_wander(t_s: np.ndarray, peak_to_peak_m: float, rng: np.random.Generator) -> np.ndarray:
    """A slow smooth wander (two sines, periods of 1.5 and 0.5 times the run, random phases) scaled to
    exactly ``peak_to_peak_m`` over the samples ``t_s``, zero mean."""
    span = max(float(t_s[-1] - t_s[0]), 1.0) if len(t_s) else 1.0
    phases = rng.uniform(0.0, 2.0 * np.pi, 2)
    x = np.sin(2.0 * np.pi * t_s / (1.5 * span) + phases[0]) + 0.3 * np.sin(2.0 * np.pi * t_s / (0.5 * span) + phases[1])
    x = x - x.mean()
    p2p = float(x.max() - x.min()) if len(x) else 0.0
    return x * (peak_to_peak_m / p2p) if p2p > 0 else x
