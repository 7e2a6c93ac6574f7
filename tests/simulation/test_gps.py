"""The simulated GPS receiver: errors with the requested statistics, NavSatFix messages that convert back
(WGS84 -> ENU) to the true antenna position within their noise, invalid fixes, the outage, truth.json."""

from __future__ import annotations

import json

import numpy as np
import pytest

from lio_cli.geometry import transform_points
from lio_cli.io.messages.decode import decode_tf
from lio_cli.io.logs.reader import open_log
from lio_cli.io.files.trajectory import read_tum
from lio_cli.simulation import build_scenario, output_paths, simulate
from lio_cli.simulation.gps import GpsSpec, gauss_markov, gps_fixes
from lio_cli.geodesy import EnuFrame

NS = 1_000_000_000
START_NS = 1_700_000_000 * NS
STD_RTOL = 0.15  # error std over 1 h of fixes with a 30 s correlation time: ~5% sampling spread
ORIGIN = (47.3769, 8.5417, 408.0)


def test_fix_errors_have_the_requested_spread_and_correlation():
    sc = build_scenario("corridor", columns=16)
    spec = GpsSpec(rate_hz=5.0, origin=ORIGIN, noise_m=(0.8, 1.6), invalid_fraction=0.05, outage_start_s=1000.0,
                   outage_s=60.0, antenna_m=(0.0, 0.0, 0.6))
    fixes = gps_fixes(sc.trajectory, spec, 0, 3600 * NS, 0, np.random.default_rng(1))
    valid = fixes.status == 0
    # converted back to ENU, each valid fix sits at the true antenna position plus its recorded error
    enu = EnuFrame(*ORIGIN).to_enu(fixes.lat_deg[valid], fixes.lon_deg[valid], fixes.alt_m[valid])
    np.testing.assert_allclose(enu - fixes.antenna_enu_m[valid], fixes.error_enu_m[valid], atol=1e-6)
    err = enu - fixes.antenna_enu_m[valid]
    np.testing.assert_allclose(err.std(axis=0), [0.8, 0.8, 1.6], rtol=STD_RTOL)
    np.testing.assert_allclose(err.mean(axis=0), 0.0, atol=0.3)
    # half the variance wanders slowly: neighbouring fixes correlate by about 0.5 * exp(-0.2 / 30)
    rho = np.corrcoef(err[:-1, 0], err[1:, 0])[0, 1]
    assert 0.4 < rho < 0.6
    # the antenna rides 0.6 m above the base origin
    st = sc.trajectory.state((fixes.stamps_ns[:5]) * 1e-9)
    np.testing.assert_allclose(fixes.antenna_enu_m[:5], st.position_m + st.R_world_base @ [0.0, 0.0, 0.6], atol=1e-12)
    # invalid fixes: NaN positions; the outage leaves a gap and costs a fix on each side
    assert np.isnan(fixes.lat_deg[~valid]).all() and np.isfinite(fixes.lat_deg[valid]).all()
    assert 0.03 < (~valid).mean() < 0.07
    gap = np.diff(fixes.stamps_ns)
    assert gap.max() == 60 * NS + 200_000_000 and (gap == 200_000_000).sum() == len(gap) - 1
    k = int(np.argmax(gap))
    assert fixes.status[k] == -1 and fixes.status[k + 1] == -1


def test_gauss_markov_is_stationary_with_the_given_sigma():
    x = gauss_markov(200_000, 0.1, np.array([2.0]), 1.0, np.random.default_rng(0))[:, 0]
    assert x.std() == pytest.approx(2.0, rel=0.03)
    np.testing.assert_allclose(np.corrcoef(x[:-10], x[10:])[0, 1], np.exp(-1.0), atol=0.03)


def test_navsatfix_messages_convert_back_to_the_ground_truth(tmp_path):
    out = tmp_path / "c.mcap"
    res = simulate("corridor", out, duration_s=6.0, seed=3, columns=16, gps=True, gps_origin=ORIGIN,
                   gps_noise_m=(0.5, 1.0), gps_outage_s=1.0, gps_invalid_fraction=0.0)
    assert res.topics["/gps/fix"]["type"] == "sensor_msgs/msg/NavSatFix"
    truth = json.loads(output_paths(out)[1].read_text())
    gps = truth["gps"]
    assert gps["origin"] == {"lat_deg": ORIGIN[0], "lon_deg": ORIGIN[1], "alt_m": ORIGIN[2]}
    assert truth["conditions"]["gps"] is True
    gt_ns, gt_poses = read_tum(output_paths(out)[0])
    with open_log(out) as log:
        fixes = [m for _, _, _, m in log.messages(["/gps/fix"])]
        tf = {t.child: t for _, _, _, m in log.messages(["/tf_static"]) for t in decode_tf(m)}
    np.testing.assert_allclose(tf["gps"].pose, np.asarray(gps["T_base_gps"]), atol=1e-12)
    stamps = np.array([m.header.stamp.sec * NS + m.header.stamp.nanosec for m in fixes])
    # 5 Hz from the start, no message inside the outage (3.3 s .. 4.3 s)
    outage = gps["outage"]
    assert (outage["start_ns"], outage["end_ns"]) == (START_NS + 3_300_000_000, START_NS + 4_300_000_000)
    expected = START_NS + np.arange(31, dtype=np.int64) * 200_000_000
    np.testing.assert_array_equal(stamps, expected[(expected < outage["start_ns"]) | (expected >= outage["end_ns"])])
    status = np.array([m.status.status for m in fixes])
    invalid = status == -1
    assert invalid.sum() == 2 and stamps[invalid].tolist() == gps["invalid_stamps_ns"]
    for m in np.array(fixes)[invalid]:
        assert np.isnan(m.latitude) and m.position_covariance_type == 0
    for m in np.array(fixes)[~invalid]:
        assert m.header.frame_id == "gps" and m.status.service == 1 and m.position_covariance_type == 2
        np.testing.assert_allclose(m.position_covariance, np.diag([0.25, 0.25, 1.0]).ravel())
    ok = np.array(fixes)[~invalid]
    enu = EnuFrame(*ORIGIN).to_enu(np.array([m.latitude for m in ok]), np.array([m.longitude for m in ok]),
                                    np.array([m.altitude for m in ok]))
    idx = np.searchsorted(gt_ns, stamps[~invalid])
    assert (gt_ns[idx] == stamps[~invalid]).all()
    antenna = np.stack([transform_points(gt_poses[i], tf["gps"].pose[:3, 3][None])[0] for i in idx])
    err = enu - antenna
    assert np.abs(err[:, :2]).max() < 4 * 0.5 and np.abs(err[:, 2]).max() < 4 * 1.0
    assert np.abs(err).max() > 0.05  # and it is noisy, not the truth itself
    np.testing.assert_allclose(np.sqrt(np.mean(np.sum(err[:, :2] ** 2, axis=1))), gps["error_rms_m"]["horizontal"],
                               rtol=1e-6)
