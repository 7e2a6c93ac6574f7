"""WGS84 conversions for the simulated GPS receiver: local ENU (east, north, up) about a geodetic origin
<-> geodetic latitude, longitude (degrees) and ellipsoidal height (m), through ECEF.

Private to the simulator (the GPS receiver model and its tests); exact to well below a millimetre near the
surface (Bowring's iteration for ECEF -> geodetic, iterated to convergence).
"""

from __future__ import annotations

import numpy as np

A_M = 6378137.0  # WGS84 semi-major axis
F = 1.0 / 298.257223563  # flattening
E2 = F * (2.0 - F)  # first eccentricity squared
B_M = A_M * (1.0 - F)
EP2 = (A_M * A_M - B_M * B_M) / (B_M * B_M)  # second eccentricity squared


def geodetic_to_ecef(lat_deg: np.ndarray, lon_deg: np.ndarray, h_m: np.ndarray) -> np.ndarray:
    """(N,3) ECEF metres of geodetic points."""
    lat, lon = np.radians(lat_deg), np.radians(lon_deg)
    sl, cl = np.sin(lat), np.cos(lat)
    n = A_M / np.sqrt(1.0 - E2 * sl * sl)
    return np.stack([(n + h_m) * cl * np.cos(lon), (n + h_m) * cl * np.sin(lon), (n * (1.0 - E2) + h_m) * sl], axis=-1)


def ecef_to_geodetic(xyz_m: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(lat deg, lon deg, height m) of ECEF points (N,3); Bowring's method, iterated to convergence."""
    x, y, z = np.asarray(xyz_m, float).T
    p = np.hypot(x, y)
    lon = np.arctan2(y, x)
    beta = np.arctan2(z * A_M, p * B_M)  # parametric latitude, first guess
    lat = beta
    for _ in range(8):
        sb, cb = np.sin(beta), np.cos(beta)
        lat = np.arctan2(z + EP2 * B_M * sb**3, p - E2 * A_M * cb**3)
        beta_new = np.arctan2((1.0 - F) * np.sin(lat), np.cos(lat))
        done = np.max(np.abs(beta_new - beta), initial=0.0) < 1e-15
        beta = beta_new
        if done:
            break
    sl, cl = np.sin(lat), np.cos(lat)
    n = A_M / np.sqrt(1.0 - E2 * sl * sl)
    # height along the normal, well conditioned at every latitude
    h = p * cl + z * sl - A_M * A_M / n
    return np.degrees(lat), np.degrees(lon), h


def _R_ecef_enu(lat_deg: float, lon_deg: float) -> np.ndarray:
    """Columns: east, north, up unit vectors of the origin, in ECEF."""
    lat, lon = np.radians(lat_deg), np.radians(lon_deg)
    sl, cl, so, co = np.sin(lat), np.cos(lat), np.sin(lon), np.cos(lon)
    return np.array([[-so, -sl * co, cl * co], [co, -sl * so, cl * so], [0.0, cl, sl]])


def enu_to_geodetic(enu_m: np.ndarray, origin: tuple[float, float, float]) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(lat deg, lon deg, height m) of ENU points (N,3) about ``origin`` = (lat deg, lon deg, height m)."""
    lat0, lon0, h0 = origin
    ecef0 = geodetic_to_ecef(np.array(lat0), np.array(lon0), np.array(h0))
    ecef = ecef0 + np.atleast_2d(enu_m) @ _R_ecef_enu(lat0, lon0).T
    return ecef_to_geodetic(ecef)


def geodetic_to_enu(lat_deg: np.ndarray, lon_deg: np.ndarray, h_m: np.ndarray,
                    origin: tuple[float, float, float]) -> np.ndarray:
    """(N,3) ENU metres of geodetic points about ``origin``."""
    lat0, lon0, h0 = origin
    d = geodetic_to_ecef(np.asarray(lat_deg, float), np.asarray(lon_deg, float), np.asarray(h_m, float))
    d = d - geodetic_to_ecef(np.array(lat0), np.array(lon0), np.array(h0))
    return np.atleast_2d(d) @ _R_ecef_enu(lat0, lon0)
