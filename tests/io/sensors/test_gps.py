"""NavSatFix decoding and GPS topics as ENU trajectories: validity, counting, origin, topic choice."""

from __future__ import annotations

import numpy as np
import pytest
from rosbags.typesys import Stores, get_typestore

from lio_cli.errors import InputError
from lio_cli.geodesy import EnuFrame
from lio_cli.io.messages.decode import KIND_TYPES, NAVSATFIX, decode_navsatfix
from lio_cli.io.sensors.gps import track_from_fixes
from lio_cli.io.logs.reader import open_log
from lio_cli.io.messages.encode import MessageFactory
from lio_cli.io.sensors.stream import SensorStream
from lio_cli.io.sensors.sources import load_trajectory

ENU_TOL_M = 1e-6  # float64 degrees keep ~1e-9 m; the tolerance leaves room for the ECEF round trip
STAMP_NS = 1_700_000_000_123_456_789
ORIGIN = EnuFrame(48.137154, 11.576124, 519.0)  # Munich
S = 1_000_000_000


@pytest.fixture(scope="module", params=[Stores.ROS1_NOETIC, Stores.ROS2_HUMBLE], ids=["ros1", "ros2"])
def make(request) -> MessageFactory:
    return MessageFactory(get_typestore(request.param))


def test_decode_keeps_status_service_and_covariance(make):
    cov = np.diag([0.04, 0.09, 0.25])
    rec = decode_navsatfix(make.navsatfix(STAMP_NS, "gps_link", 48.1, 11.5, 520.25, status=2, service=9,
                                          covariance_m2=cov, covariance_type=2))
    assert (rec.stamp_ns, rec.frame_id, rec.status, rec.service, rec.covariance_type) == (STAMP_NS, "gps_link", 2, 9, 2)
    assert (rec.latitude_deg, rec.longitude_deg, rec.altitude_m) == (48.1, 11.5, 520.25)
    np.testing.assert_array_equal(rec.position_covariance_m2, cov)
    assert rec.valid and rec.invalid_reason is None


def test_invalid_fixes_say_why(make):
    assert decode_navsatfix(make.navsatfix(STAMP_NS, "gps", 48.1, 11.5, 520.0, status=-1)).invalid_reason == "no fix"
    rec = decode_navsatfix(make.navsatfix(STAMP_NS, "gps", float("nan"), 11.5, 520.0))
    assert rec.invalid_reason == "NaN or infinite coordinate" and not rec.valid
    assert decode_navsatfix(make.navsatfix(STAMP_NS, "gps", 48.1, 200.0, 0.0)).invalid_reason == \
        "longitude 200 outside -180..180 deg"
    assert KIND_TYPES["gps"] == (NAVSATFIX,)


def _enu_path(n: int) -> np.ndarray:
    t = np.arange(n) * 0.5
    return np.stack([20.0 * np.sin(0.1 * t), 3.0 * t, 0.2 * t], axis=1)


def _gps_log(logs, fmt: str, enu: np.ndarray, status=None, extra_topic: str | None = None, name=None):
    lat, lon, alt = ORIGIN.to_geodetic(enu)
    status = np.zeros(len(enu), int) if status is None else status

    def build(w):
        w.add_topic("/fix", NAVSATFIX)
        for k in range(len(enu)):
            stamp = STAMP_NS + k * S // 2
            w.write("/fix", stamp + 1000, w.make.navsatfix(stamp, "gps", lat[k], lon[k], alt[k], status=int(status[k])))
        if extra_topic:
            w.add_topic(extra_topic, NAVSATFIX)
            w.write(extra_topic, STAMP_NS, w.make.navsatfix(STAMP_NS, "gps", 1.0, 2.0, 3.0))

    return logs.write(fmt, build, name)


def test_gps_topic_loads_as_enu_positions(logs, write_format):
    enu = _enu_path(12)
    path = _gps_log(logs, write_format, enu)
    traj = load_trajectory(f"{path}:/fix")
    assert traj.kind == "gps" and traj.position_only and len(traj) == 12
    np.testing.assert_array_equal(traj.stamps_ns, STAMP_NS + np.arange(12) * S // 2)
    np.testing.assert_allclose(traj.poses[:, :3, 3], enu, atol=ENU_TOL_M)  # the first fix is ORIGIN here
    np.testing.assert_array_equal(traj.poses[:, :3, :3], np.repeat(np.eye(3)[None], 12, axis=0))
    assert traj.gps.origin_source == "first valid fix"
    np.testing.assert_allclose([traj.gps.origin.lat_deg, traj.gps.origin.lon_deg, traj.gps.origin.alt_m],
                               [ORIGIN.lat_deg, ORIGIN.lon_deg, ORIGIN.alt_m], atol=1e-9)


def test_invalid_fixes_are_dropped_and_counted_and_origin_is_first_valid(logs):
    enu = _enu_path(10) + np.array([100.0, 50.0, 2.0])
    status = np.array([-1, -1, 0, 0, -1, 1, 2, 0, 0, 0])
    path = _gps_log(logs, "ros1", enu, status)
    traj = load_trajectory(f"{path}:/fix")
    keep = status >= 0
    assert len(traj) == 7 and traj.gps.no_fix == 3 and traj.gps.messages == 10 and traj.gps.dropped == 3
    first = ORIGIN.to_geodetic(enu[2])  # the first valid fix is the origin
    o = traj.gps.origin
    np.testing.assert_allclose([o.lat_deg, o.lon_deg, o.alt_m], np.ravel(first), rtol=0, atol=1e-9)
    np.testing.assert_allclose(traj.poses[0, :3, 3], 0.0, atol=ENU_TOL_M)
    # 100 m from ORIGIN the ENU axes tilt by 100 m / 6.4e6 m = 1.6e-5 rad: displacements agree to that
    np.testing.assert_allclose(traj.poses[:, :3, 3], enu[keep] - enu[2], atol=1.6e-5 * 30)
    given = load_trajectory(f"{path}:/fix", origin=ORIGIN)
    np.testing.assert_allclose(given.poses[:, :3, 3], enu[keep], atol=ENU_TOL_M)
    assert given.gps.origin_source == "given"
    assert given.gps.describe() == (
        f"GPS /fix: 7 of 10 fixes used (dropped 3 without a fix); ENU origin 48.13715400, 11.57612400, "
        f"519.000 m (given)")


def test_topic_without_a_valid_fix_is_bad_input(logs):
    enu = _enu_path(4)
    path = _gps_log(logs, "ros1", enu, np.array([-1, -1, -1, -1]))
    with pytest.raises(InputError) as err:
        load_trajectory(f"{path}:/fix")
    assert str(err.value) == (f"{path}: topic /fix: no valid fix among its 4 NavSatFix messages (4 without a fix "
                              f"(status NO_FIX), 0 with NaN or out-of-range coordinates)")


def test_bare_log_uses_its_only_gps_topic_and_refuses_two(logs):
    path = _gps_log(logs, "mcap", _enu_path(5))
    assert load_trajectory(str(path)).kind == "gps"
    two = _gps_log(logs, "mcap", _enu_path(5), extra_topic="/gps2")
    with pytest.raises(InputError) as err:
        load_trajectory(str(two))
    assert str(err.value) == f"{two}: no ground-truth pose topic and several GPS topics (/fix, /gps2); name one as LOG:/topic"


def test_stream_counts_repeated_stamps(logs):
    def build(w):
        w.add_topic("/fix", NAVSATFIX)
        for k, stamp in enumerate((STAMP_NS, STAMP_NS + S, STAMP_NS + S, STAMP_NS + 2 * S)):
            w.write("/fix", stamp + k, w.make.navsatfix(stamp, "gps", 48.0, 11.0 + 1e-5 * k, 500.0))

    path = logs.write("ros1", build)
    with open_log(path) as log:
        stream = SensorStream(log, {"gps": "/fix"}, strict=False)
        recs = list(stream)
    assert [r.kind for r in recs] == ["gps"] * 3 and stream.stats.duplicates == {"/fix": 1}
    traj = load_trajectory(f"{path}:/fix")
    assert len(traj) == 3 and traj.gps.bad_stamps == 1 and traj.gps.messages == 4


def test_track_from_fixes_counts_bad_coordinates(make):
    fixes = [decode_navsatfix(make.navsatfix(STAMP_NS + k, "gps", lat, 11.0, 500.0))
             for k, lat in enumerate((48.0, float("nan"), 95.0, 48.00001))]
    track = track_from_fixes("/fix", fixes)
    assert len(track) == 2 and track.bad_coordinates == 2 and track.no_fix == 0
    assert track.summary()["dropped_bad_coordinates"] == 2
    np.testing.assert_allclose(track.enu_m[1], EnuFrame(48.0, 11.0, 500.0).to_enu(48.00001, 11.0, 500.0), atol=1e-9)


def test_an_absurd_altitude_is_a_bad_coordinate_not_the_origin(make):
    # the first fix at -1e300 m used to become the ENU origin, overflowing fuse and evaluate (fuzz, issue 32)
    fixes = [decode_navsatfix(make.navsatfix(STAMP_NS + k, "gps", 48.0, 11.0, alt))
             for k, alt in enumerate((-1e300, 500.0, 1e7, 501.0))]
    assert fixes[0].invalid_reason == "altitude -1e+300 m outside -20000..1e+06 m"
    track = track_from_fixes("/fix", fixes)
    assert len(track) == 2 and track.bad_coordinates == 2 and track.origin == EnuFrame(48.0, 11.0, 500.0)
    np.testing.assert_allclose(track.enu_m[1], [0.0, 0.0, 1.0], atol=1e-6)
