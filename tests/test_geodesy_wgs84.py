"""WGS84 conversions: published ECEF values, exact up offsets, round trips, local radii of curvature."""

from __future__ import annotations

import numpy as np
import pytest

from lio_cli.geodesy import WGS84_A_M as A_M
from lio_cli.geodesy import WGS84_B_M as B_M
from lio_cli.geodesy import EnuFrame, ecef_to_geodetic, geodetic_to_ecef

ECEF_TOL_M = 1e-3
ROUND_TRIP_TOL_M = 1e-6
ANGLE_TOL_DEG = 1e-11  # about 1 micrometre on the ground


def test_geodetic_to_ecef_matches_published_values():
    pts = geodetic_to_ecef(np.array([0.0, 90.0, 45.0, -45.0]), np.array([0.0, 0.0, 45.0, -135.0]),
                           np.array([0.0, 0.0, 0.0, 1000.0]))
    np.testing.assert_allclose(pts[0], [A_M, 0.0, 0.0], atol=ECEF_TOL_M)
    np.testing.assert_allclose(pts[1], [0.0, 0.0, B_M], atol=ECEF_TOL_M)
    # (45 deg, 45 deg, 0 m): the reference value used by pymap3d and most geodesy texts
    np.testing.assert_allclose(pts[2], [3194419.145061, 3194419.145061, 4487348.408802], atol=ECEF_TOL_M)
    # the southern, western mirror image 1 km up: same magnitudes plus 1 km along the normal
    normal = np.array([-0.5, -0.5, -np.sqrt(0.5)])
    np.testing.assert_allclose(pts[3], np.array([-1, -1, -1]) * pts[2] + 1000.0 * normal, atol=ECEF_TOL_M)


@pytest.mark.parametrize("origin", [(48.137154, 11.576124, 519.0), (-33.8568, 151.2153, 5.0), (0.0, 179.9999, -20.0),
                                    (78.2232, 15.6267, 30.0)])
def test_enu_round_trip_and_pure_up_offset(origin):
    rng = np.random.default_rng(4)
    enu = np.column_stack([rng.uniform(-50e3, 50e3, 200), rng.uniform(-50e3, 50e3, 200), rng.uniform(-500, 3000, 200)])
    frame = EnuFrame(*origin)
    lat, lon, alt = frame.to_geodetic(enu)
    np.testing.assert_allclose(frame.to_enu(lat, lon, alt), enu, atol=ROUND_TRIP_TOL_M)
    ecef = geodetic_to_ecef(lat, lon, alt)
    lat2, lon2, alt2 = ecef_to_geodetic(ecef)
    np.testing.assert_allclose(np.column_stack([lat2, lon2]), np.column_stack([lat, lon]), atol=ANGLE_TOL_DEG)
    np.testing.assert_allclose(alt2, alt, atol=ROUND_TRIP_TOL_M)
    # straight up from the origin is along the ellipsoid normal: latitude and longitude stay, height grows
    lat, lon, alt = frame.to_geodetic(np.array([[0.0, 0.0, 0.0], [0.0, 0.0, 123.4]]))
    np.testing.assert_allclose(lat, origin[0], atol=ANGLE_TOL_DEG)
    np.testing.assert_allclose(lon, origin[1], atol=ANGLE_TOL_DEG)
    np.testing.assert_allclose(alt, [origin[2], origin[2] + 123.4], atol=ROUND_TRIP_TOL_M)


def test_small_offsets_follow_the_local_radii_of_curvature():
    """Independent first-order check: 100 m north/east change latitude/longitude by 100 m over the meridian
    and prime-vertical radii (to better than 1 mm)."""
    lat0, lon0, h0 = 48.137154, 11.576124, 519.0
    e2 = 1.0 - (B_M / A_M) ** 2
    s = np.sin(np.radians(lat0))
    n = A_M / np.sqrt(1 - e2 * s * s)
    m = A_M * (1 - e2) / (1 - e2 * s * s) ** 1.5
    lat, lon, _ = EnuFrame(lat0, lon0, h0).to_geodetic(np.array([[0.0, 100.0, 0.0], [100.0, 0.0, 0.0]]))
    assert np.radians(lat[0] - lat0) * (m + h0) == pytest.approx(100.0, abs=1e-3)
    assert np.radians(lon[1] - lon0) * (n + h0) * np.cos(np.radians(lat0)) == pytest.approx(100.0, abs=1e-3)
