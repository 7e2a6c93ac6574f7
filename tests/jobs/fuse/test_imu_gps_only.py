"""IMU + consumer GPS and nothing else (a drone, no wheels, no odometry): the filter must end near the fixes,
not hundreds of metres off. Two failures this guards: a multipath jump whose end the GPS-only jump test
missed kept the fixes out for 30 s while the IMU drifted (the filter now re-admits them when it agrees with
them or knows less than the jump's size), and a moving start no other source measures gave the heading fit a
zero start velocity (it now fits the velocity too)."""

from __future__ import annotations

import numpy as np
from lio_cli.config.fuse import FuseConfig
from lio_cli.io.files.trajectory import read_tum
from lio_cli.jobs.fuse.job import FuseJob, run_fuse
from lio_cli.simulation.run import simulate

from .test_consumer_gps import _ate_h

GPS_RATIO = 1.0  # fused horizontal ATE vs the fixes' own (before the fix 93: 252 m against 2.7)


def test_imu_and_consumer_gps_end_near_the_fixes(tmp_path):
    log = tmp_path / "drone.mcap"
    simulate("drone", log, duration_s=45.0, seed=7, start="moving", gps=True, gps_model="consumer", lidar=False)
    gt = read_tum(log.with_name("drone.gt.tum"))
    run = run_fuse(FuseJob(log, FuseConfig(rate_hz=20.0)))
    gps = run.sources.inputs.gps
    ok = np.isfinite(gps.position_enu_m[:, 0])
    gps_alone = _ate_h(gt, gps.stamps_ns[ok], gps.position_enu_m[ok])
    fused = _ate_h(gt, run.trajectory.stamps_ns, run.trajectory.positions)
    assert fused < GPS_RATIO * gps_alone, (fused, gps_alone)
    g = run.metrics["sources"]["gps"]
    assert g["updates"] > 0.6 * len(gps)  # the fixes after the jump are used, not held out for 30 s
