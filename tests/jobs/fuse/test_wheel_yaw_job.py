"""The wheels' yaw rate weighed against the gyro (core/fuse/wheel_yaw.py) through ``run_fuse``: a noise-free log has
no slip, and a run fused in chunks reports and uses the whole log's weighing."""

from __future__ import annotations

from lio_cli.config.fuse import FuseConfig
from lio_cli.jobs.fuse import FuseJob, run_fuse
from lio_cli.simulation.run import simulate


def test_an_ideal_log_has_no_yaw_slip(tmp_path):
    log = tmp_path / "ideal.bag"
    simulate("planar", log, duration_s=15.0, noise_scale=0.0)
    run = run_fuse(FuseJob(log, FuseConfig(smooth=False)))
    check = run.metrics["core"]["wheel_yaw_check"]
    # the gate without a floor: 145 of 751 samples far (the wheel's rate against the gyro's mean at every kink of
    # the yaw rate), with the gyro's yaw acceleration over half a wheel period: none
    assert check["used"] and check["far_samples"] == 0, check
    assert "yaw_slip" not in run.metrics["rejected"].get("wheel", {})


def test_a_run_fused_in_chunks_uses_and_reports_the_whole_log_s_weighing(tmp_path):
    log = tmp_path / "slips.bag"
    simulate("planar", log, duration_s=60.0, wheel_errors=False, wheel_slip_bursts=2)
    whole = run_fuse(FuseJob(log, FuseConfig(smooth=False)))
    chunked = run_fuse(FuseJob(log, FuseConfig(smooth=False, max_memory_mb=22.0)))
    assert whole.metrics["memory"]["chunks"] == 1 and chunked.metrics["memory"]["chunks"] == 2
    check = chunked.metrics["core"]["wheel_yaw_check"]
    # each chunk weighed its own 40-50 s before and the first one's check was reported: 73 far samples, not 184
    assert check == whole.metrics["core"]["wheel_yaw_check"] and check["used"] and check["far_samples"] > 100
    assert chunked.metrics["rejected"]["wheel"] == whole.metrics["rejected"]["wheel"] == {
        "yaw_slip": check["far_samples"], "yaw_unchecked": check["unchecked_samples"]}
