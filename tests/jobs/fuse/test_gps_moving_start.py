"""A car already cruising straight when the log starts, fused from its IMU and GPS alone (no wheels): at a constant
velocity the IMU reads as at rest, so the start was taken as standing (zero velocity) and 2 cm fixes could not
save it (16.8 m ATE smoothed, 141 m filtered). The fixes' own speed over the start window now says it moves; fixes
at rest, metres of noise, leave a standing start standing."""

from __future__ import annotations

import pytest

from lio_cli.config.fuse import FuseConfig
from lio_cli.jobs.fuse import FuseJob, run_fuse
from lio_cli.simulation.run import simulate

from .test_gps_antenna import _ate

IMU_GPS = {"imu": ["accel", "gyro"], "gps": ["position"]}


@pytest.mark.parametrize("smooth, limit", [(True, 0.05), (False, 0.1)])
def test_a_cruising_start_is_found_by_the_fixes(tmp_path, smooth, limit):
    log = tmp_path / "cruise.mcap"
    simulate("drive", log, duration_s=30.0, seed=7, start="moving", lidar=False, gps=True, gps_noise_m=(0.02, 0.04),
             gps_outage_s=0.0)
    run = run_fuse(FuseJob(log, FuseConfig(smooth=smooth, use=IMU_GPS)))
    assert run.metrics["start"].startswith("moving start at constant velocity (the GPS fixes move 7.4")
    # measured: 0.014 m smoothed, 0.028 filtered (the start taken as standing: 16.8 and 141 m)
    assert _ate(log, run.trajectory) < limit


@pytest.mark.parametrize("seed", [7, 8])
def test_consumer_fixes_at_rest_leave_a_standing_start_standing(tmp_path, seed):
    log = tmp_path / "still.mcap"
    simulate("drone", log, duration_s=10.0, seed=seed, start="still", lidar=False, gps=True, gps_model="consumer")
    run = run_fuse(FuseJob(log, FuseConfig(smooth=False)))
    assert run.metrics["start"].startswith("standing start"), run.metrics["start"]
