"""A car with consumer GPS whose odometry input loses track (turns away, tens of metres off): the fused path
must stay near the fixes. Before the fix the odometry's gate resets (forced in after 5 rejections) inflated
the covariance again and again while the GPS was held out, and the filter diverged (5e5 m on the matrix)."""

from __future__ import annotations

import numpy as np

from lio_cli.config.fuse import FuseConfig
from lio_cli.geometry import so3_exp
from lio_cli.io.files.trajectory import format_tum, read_tum
from lio_cli.jobs.fuse.job import FuseJob, run_fuse
from lio_cli.simulation.run import simulate

from .test_consumer_gps import _ate_h

GPS_RATIO = 0.8  # fused horizontal ATE vs the fixes' own


def _lost(stamps_ns: np.ndarray, poses: np.ndarray, after_s: float) -> np.ndarray:
    """The poses re-chained from their increments, which from ``after_s`` on lose track as ``lio odom``'s did on
    the matrix's car: a tenth of the true step for 5 s, then twice it, turning 3 deg/s the wrong way."""
    t = (stamps_ns - stamps_ns[0]) * 1e-9
    out = poses.copy()
    for k in range(1, len(poses)):
        d = np.linalg.inv(poses[k - 1]) @ poses[k]
        if t[k] > after_s:
            d[:3, 3] *= 0.1 if t[k] < after_s + 5.0 else 2.0
            d[:3, :3] = so3_exp(np.array([0.0, 0.0, np.radians(3.0) * (t[k] - t[k - 1])])) @ d[:3, :3]
        out[k] = out[k - 1] @ d
    return out


def test_lost_odometry_does_not_pull_the_filter_away_from_gps(tmp_path):
    log = tmp_path / "car.mcap"
    simulate("drive", log, duration_s=30.0, seed=7, start="moving", gps=True, gps_model="consumer", lidar=False)
    gst, gpo = read_tum(log.with_name("car.gt.tum"))
    odom = tmp_path / "car.odom.tum"
    lost = _lost(gst[::10], gpo[::10], 8.0)
    odom.write_text(format_tum(gst[::10], lost))
    assert _ate_h((gst, gpo), gst[::10], lost[:, :3, 3]) > 15.0  # the odometry alone is far off
    run = run_fuse(FuseJob(log, FuseConfig.model_validate({"input": {"odom_file": str(odom)}, "rate_hz": 20.0})))
    gps = run.sources.inputs.gps
    ok = np.isfinite(gps.position_enu_m[:, 0])
    gps_alone = _ate_h((gst, gpo), gps.stamps_ns[ok], gps.position_enu_m[ok])
    fused = _ate_h((gst, gpo), run.trajectory.stamps_ns, run.trajectory.positions)
    assert fused < GPS_RATIO * gps_alone, (fused, gps_alone)
    assert np.ptp(run.trajectory.positions[:, 2]) < 60.0  # no vertical excursion (the fixes' altitude wanders 25 m)
    odo = run.metrics["sources"]["odom"]
    assert odo["rejected"]["outlier"]["count"] > 100  # the lost increments, rejected and counted
    assert "gate_reset" not in odo["handled"]
