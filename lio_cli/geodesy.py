"""WGS84 geodesy: latitude/longitude/altitude <-> ECEF <-> a local east-north-up (ENU) frame. Pure numpy.

Latitude and longitude are geodetic, in degrees; altitude is the height above the WGS84 ellipsoid in metres
(what sensor_msgs/NavSatFix carries). ECEF is the Earth-centred, Earth-fixed frame (x through lat 0 lon 0,
z through the north pole). An ``EnuFrame`` is the tangent frame at an origin: x east, y north, z up along the
ellipsoid normal, so positions in it read as the ``world`` frame of DESIGN.md (z up).

Forward: ``p_ecef = ((N + h) cos(lat) cos(lon), (N + h) cos(lat) sin(lon), (N (1 - e^2) + h) sin(lat))`` with
``N = a / sqrt(1 - e^2 sin^2(lat))``. Inverse: Bowring's iteration on the reduced latitude (converged to
machine precision for any point above the Earth's centre region), with the height from
``h = p cos(lat) + z sin(lat) - a sqrt(1 - e^2 sin^2(lat))``, which stays exact at the poles.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

WGS84_A_M = 6378137.0  # semi-major axis
WGS84_F = 1.0 / 298.257223563  # flattening
WGS84_B_M = WGS84_A_M * (1.0 - WGS84_F)  # semi-minor axis
WGS84_E2 = WGS84_F * (2.0 - WGS84_F)  # first eccentricity squared
WGS84_EP2 = WGS84_E2 / (1.0 - WGS84_E2)  # second eccentricity squared
_BOWRING_ITERATIONS = 4  # each step gains more than 6 digits of latitude; 4 reach float64 resolution


def geodetic_to_ecef(lat_deg, lon_deg, alt_m) -> np.ndarray:
    """ECEF position(s) in metres, shape (..., 3), of geodetic latitude/longitude (deg) and height (m)."""
    lat = np.deg2rad(np.asarray(lat_deg, dtype=np.float64))
    lon = np.deg2rad(np.asarray(lon_deg, dtype=np.float64))
    h = np.asarray(alt_m, dtype=np.float64)
    sin_lat, cos_lat = np.sin(lat), np.cos(lat)
    n = WGS84_A_M / np.sqrt(1.0 - WGS84_E2 * sin_lat**2)
    return np.stack([(n + h) * cos_lat * np.cos(lon), (n + h) * cos_lat * np.sin(lon),
                     (n * (1.0 - WGS84_E2) + h) * sin_lat], axis=-1)


def ecef_to_geodetic(xyz_m) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(latitude deg, longitude deg, height m) of ECEF position(s) (..., 3)."""
    xyz = np.asarray(xyz_m, dtype=np.float64)
    x, y, z = xyz[..., 0], xyz[..., 1], xyz[..., 2]
    p = np.hypot(x, y)
    beta = np.arctan2(z, (1.0 - WGS84_F) * p)  # reduced latitude, first guess
    for _ in range(_BOWRING_ITERATIONS):
        lat = np.arctan2(z + WGS84_EP2 * WGS84_B_M * np.sin(beta) ** 3, p - WGS84_E2 * WGS84_A_M * np.cos(beta) ** 3)
        beta = np.arctan2((1.0 - WGS84_F) * np.sin(lat), np.cos(lat))
    sin_lat = np.sin(lat)
    h = p * np.cos(lat) + z * sin_lat - WGS84_A_M * np.sqrt(1.0 - WGS84_E2 * sin_lat**2)
    return np.rad2deg(lat), np.rad2deg(np.arctan2(y, x)), h


def rotation_enu_ecef(lat_deg: float, lon_deg: float) -> np.ndarray:
    """``R_enu_ecef`` (3,3): rows are the east, north and up unit vectors at (lat, lon), in ECEF."""
    lat, lon = np.deg2rad(float(lat_deg)), np.deg2rad(float(lon_deg))
    sl, cl, so, co = np.sin(lat), np.cos(lat), np.sin(lon), np.cos(lon)
    return np.array([[-so, co, 0.0], [-sl * co, -sl * so, cl], [cl * co, cl * so, sl]])


ALTITUDE_RANGE_M = (-20_000.0, 1_000_000.0)  # below any ocean floor, above any receiver short of an orbit


def check_geodetic(lat_deg: float, lon_deg: float, alt_m: float) -> str | None:
    """Why (lat, lon, alt) is not a usable geodetic position, or None when it is."""
    values = (lat_deg, lon_deg, alt_m)
    if not all(np.isfinite(v) for v in values):
        return "NaN or infinite coordinate"
    if abs(lat_deg) > 90.0:
        return f"latitude {lat_deg:g} outside -90..90 deg"
    if abs(lon_deg) > 180.0:
        return f"longitude {lon_deg:g} outside -180..180 deg"
    if not ALTITUDE_RANGE_M[0] <= alt_m <= ALTITUDE_RANGE_M[1]:
        return f"altitude {alt_m:g} m outside {ALTITUDE_RANGE_M[0]:g}..{ALTITUDE_RANGE_M[1]:g} m"
    return None


@dataclass(frozen=True)
class EnuFrame:
    """A local east-north-up frame whose origin is a geodetic position (deg, deg, m above the ellipsoid)."""

    lat_deg: float
    lon_deg: float
    alt_m: float

    @property
    def origin_ecef_m(self) -> np.ndarray:
        return geodetic_to_ecef(self.lat_deg, self.lon_deg, self.alt_m)

    @property
    def R_enu_ecef(self) -> np.ndarray:  # noqa: N802 - the frame convention is the name
        return rotation_enu_ecef(self.lat_deg, self.lon_deg)

    def ecef_to_enu(self, xyz_m) -> np.ndarray:
        """ENU position(s) (..., 3) of ECEF position(s)."""
        return (np.asarray(xyz_m, dtype=np.float64) - self.origin_ecef_m) @ self.R_enu_ecef.T

    def enu_to_ecef(self, enu_m) -> np.ndarray:
        """ECEF position(s) (..., 3) of ENU position(s)."""
        return np.asarray(enu_m, dtype=np.float64) @ self.R_enu_ecef + self.origin_ecef_m

    def to_enu(self, lat_deg, lon_deg, alt_m) -> np.ndarray:
        """ENU position(s) (..., 3) in metres of geodetic position(s)."""
        return self.ecef_to_enu(geodetic_to_ecef(lat_deg, lon_deg, alt_m))

    def to_geodetic(self, enu_m) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(latitude deg, longitude deg, height m) of ENU position(s) (..., 3)."""
        return ecef_to_geodetic(self.enu_to_ecef(enu_m))

    def to_dict(self) -> dict[str, float]:
        return {"lat_deg": self.lat_deg, "lon_deg": self.lon_deg, "alt_m": self.alt_m}
