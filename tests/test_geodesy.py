"""WGS84 geodesy against published ECEF values, closed-form special cases and round trips."""

from __future__ import annotations

import numpy as np
import pytest

from lio_cli.geodesy import (
    WGS84_A_M,
    WGS84_E2,
    EnuFrame,
    check_geodetic,
    ecef_to_geodetic,
    geodetic_to_ecef,
    rotation_enu_ecef,
)

PUBLISHED_TOL_M = 1e-8  # the nvector example is printed to 1e-8 m
ROUND_TRIP_DEG = 1e-12
ROUND_TRIP_M = 1e-7
ENU_TOL_M = 1e-8


def test_published_ecef_examples():
    # nvector documentation, example 4 ("geodetic latitude to ECEF vector"): lat 1 deg, lon 2 deg, height 3 m
    np.testing.assert_allclose(geodetic_to_ecef(1.0, 2.0, 3.0), [6373290.27721828, 222560.20067474, 110568.82718179],
                               rtol=0, atol=PUBLISHED_TOL_M)
    # GeographicLib example-Geocentric.cpp: Mt Everest (27.99, 86.93, 8820 m) prints 302 5636 2980 km
    np.testing.assert_array_equal(np.floor(geodetic_to_ecef(27.99, 86.93, 8820.0) / 1000 + 0.5), [302, 5636, 2980])
    # the equator at lon 0 is one semi-major axis out on x; the pole is the semi-minor axis up z
    np.testing.assert_allclose(geodetic_to_ecef(0.0, 0.0, 0.0), [WGS84_A_M, 0, 0], atol=PUBLISHED_TOL_M)
    np.testing.assert_allclose(geodetic_to_ecef(90.0, 0.0, 10.0), [0, 0, 6356752.314245179 + 10.0], atol=PUBLISHED_TOL_M)


def test_round_trip_everywhere_including_poles_and_antimeridian():
    rng = np.random.default_rng(4)
    lat = np.concatenate([rng.uniform(-90, 90, 5000), [90.0, -90.0, 0.0, 89.9999999, -45.0]])
    lon = np.concatenate([rng.uniform(-180, 180, 5000), [0.0, 10.0, 180.0, -179.9999999, 179.9999999]])
    alt = np.concatenate([rng.uniform(-500, 30_000, 5000), [0.0, 100.0, -100.0, 5.0, 8848.0]])
    la, lo, h = ecef_to_geodetic(geodetic_to_ecef(lat, lon, alt))
    np.testing.assert_allclose(la, lat, rtol=0, atol=ROUND_TRIP_DEG)
    not_pole = np.abs(lat) < 90.0  # longitude is undefined on the poles
    dlon = (lo - lon + 180.0) % 360.0 - 180.0
    np.testing.assert_allclose(dlon[not_pole], 0.0, atol=ROUND_TRIP_DEG)
    np.testing.assert_allclose(h, alt, rtol=0, atol=ROUND_TRIP_M)


def test_enu_closed_form_cases():
    frame = EnuFrame(0.0, 0.0, 0.0)
    np.testing.assert_allclose(frame.to_enu(0.0, 0.0, 0.0), [0, 0, 0], atol=ENU_TOL_M)
    np.testing.assert_allclose(frame.to_enu(0.0, 0.0, 100.0), [0, 0, 100.0], atol=ENU_TOL_M)
    # along the equator: the point sits on a circle of radius a, seen from its tangent plane at lon 0
    dlon = np.deg2rad(0.01)
    np.testing.assert_allclose(frame.to_enu(0.0, 0.01, 0.0),
                               [WGS84_A_M * np.sin(dlon), 0.0, WGS84_A_M * (np.cos(dlon) - 1.0)], atol=ENU_TOL_M)
    # a micro-step north at 48 deg moves north by the meridian radius of curvature times the angle
    lat0 = 48.0
    frame = EnuFrame(lat0, 11.0, 500.0)
    s2 = np.sin(np.deg2rad(lat0)) ** 2
    m = WGS84_A_M * (1 - WGS84_E2) / (1 - WGS84_E2 * s2) ** 1.5
    dphi_deg = 1e-7
    east, north, up = frame.to_enu(lat0 + dphi_deg, 11.0, 500.0)
    assert north == pytest.approx((m + 500.0) * np.deg2rad(dphi_deg), rel=1e-6)
    assert abs(east) < ENU_TOL_M and abs(up) < 1e-6
    # a step east moves by the prime-vertical radius of the parallel
    n = WGS84_A_M / np.sqrt(1 - WGS84_E2 * s2)
    east, north, up = frame.to_enu(lat0, 11.0 + dphi_deg, 500.0)
    assert east == pytest.approx((n + 500.0) * np.cos(np.deg2rad(lat0)) * np.deg2rad(dphi_deg), rel=1e-6)


def test_enu_round_trip_and_rotation():
    frame = EnuFrame(-33.8568, 151.2153, 40.0)
    rng = np.random.default_rng(5)
    enu = rng.uniform(-5000, 5000, (200, 3))
    lat, lon, alt = frame.to_geodetic(enu)
    np.testing.assert_allclose(frame.to_enu(lat, lon, alt), enu, rtol=0, atol=ROUND_TRIP_M)
    R = rotation_enu_ecef(-33.8568, 151.2153)
    np.testing.assert_allclose(R @ R.T, np.eye(3), atol=1e-15)
    assert np.linalg.det(R) == pytest.approx(1.0, abs=1e-15)
    up = geodetic_to_ecef(-33.8568, 151.2153, 1.0) - geodetic_to_ecef(-33.8568, 151.2153, 0.0)
    np.testing.assert_allclose(R[2], up, atol=1e-9)  # up is the ellipsoid normal
    assert frame.to_dict() == {"lat_deg": -33.8568, "lon_deg": 151.2153, "alt_m": 40.0}


def test_check_geodetic_says_what_is_wrong():
    assert check_geodetic(48.0, 11.0, 500.0) is None
    assert check_geodetic(float("nan"), 11.0, 500.0) == "NaN or infinite coordinate"
    assert check_geodetic(48.0, 11.0, float("inf")) == "NaN or infinite coordinate"
    assert check_geodetic(91.0, 11.0, 0.0) == "latitude 91 outside -90..90 deg"
    assert check_geodetic(48.0, -181.5, 0.0) == "longitude -181.5 outside -180..180 deg"
    assert check_geodetic(48.0, 11.0, -1e300) == "altitude -1e+300 m outside -20000..1e+06 m"
    assert check_geodetic(48.0, 11.0, 35_786_000.0) == "altitude 3.5786e+07 m outside -20000..1e+06 m"
    assert check_geodetic(31.5, 35.4, -430.0) is None and check_geodetic(27.99, 86.93, 8849.0) is None
