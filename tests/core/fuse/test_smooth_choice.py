"""Which smoother ``fuse(..., smooth=True)`` runs: the factor graph with the accelerometer whatever the filter
(planar with GPS or odometry, complementary), the planar RTS pass on IMU + wheels alone, none for the
complementary filter without an accelerometer; ``smooth=False`` the filter alone."""

from __future__ import annotations

import numpy as np
import pytest

from lio_cli.core.fuse import FuseOptions, fuse, graph_smooths, planar
from lio_cli.evaluation import EvalOptions, Trajectory, evaluate
from lio_cli.simulation.fusion_case import OdomNoise, simulate_case


def ate(case, res) -> float:
    ref = Trajectory(case.truth_stamps_ns, case.truth_poses, "gt")
    est = Trajectory(res.stamps_ns, res.poses, "est")
    return evaluate(ref, est, EvalOptions(align="se3")).stats["ape"]["trans"]["rmse"]


@pytest.fixture(scope="module")
def gps_case():
    return simulate_case("planar", 20.0, seed=1, gps_sigma_m=1.0)


def test_the_planar_filter_with_gps_is_smoothed_by_the_graph(gps_case):
    filt = fuse(gps_case.inputs, FuseOptions(estimator="planar", rate_hz=20.0))
    smooth = fuse(gps_case.inputs, FuseOptions(estimator="planar", rate_hz=20.0, smooth=True))
    sm = smooth.info["smoother"]
    assert smooth.estimator == "planar" and smooth.smoothed and not filt.smoothed
    assert sm["kind"] == "factor_graph" and sm["fallback"] is None and sm["initial_filter"] == "ekf"
    assert "accel" in smooth.info["use"]["imu"] and "accel" not in filt.info["use"]["imu"]
    assert np.array_equal(smooth.stamps_ns, filt.stamps_ns)
    assert ate(gps_case, smooth) < 0.8 * ate(gps_case, filt)


def test_imu_and_wheels_alone_keep_the_planar_rts_pass(gps_case):
    inputs = gps_case.inputs
    no_gps = type(inputs)(imu=inputs.imu, wheel=inputs.wheel)
    smooth = fuse(no_gps, FuseOptions(estimator="planar", rate_hz=20.0, smooth=True))
    assert smooth.smoothed and smooth.estimator == "planar" and smooth.info["smoother"]["kind"] == "rts"
    # the filter left the accelerometer out (the graph would take it); the heave's height is all it gave
    assert "heave" in smooth.info and smooth.info["use"]["imu"] == ["accel", "gyro"]


def test_the_complementary_filter_is_smoothed_by_the_graph_or_not_at_all(gps_case):
    graph = fuse(gps_case.inputs, FuseOptions(estimator="complementary", rate_hz=20.0, smooth=True))
    assert graph.smoothed and graph.estimator == "complementary" and graph.info["smoother"]["kind"] == "factor_graph"
    gyro = {"imu": {"gyro"}, "wheel": {"speed"}}
    alone = fuse(gps_case.inputs, FuseOptions(estimator="complementary", rate_hz=20.0, smooth=True, use=gyro))
    assert not alone.smoothed and alone.info["smoother"]["kind"] is None


def test_graph_smooths_by_selection_and_filter():
    iw = {"imu": ["gyro", "accel"], "wheel": ["speed"]}
    assert graph_smooths(iw, "ekf") and graph_smooths(iw, "complementary")
    assert not graph_smooths(iw, "planar")
    assert graph_smooths({**iw, "gps": ["position"]}, "planar")
    assert not graph_smooths({**iw, "odom": ["delta"]}, "planar")  # beside odometry the wheels agree with
    assert not graph_smooths({"imu": ["gyro"], "wheel": ["speed"], "gps": ["position"]}, "ekf")


def test_the_planar_filter_where_its_rts_pass_cannot_invert_keeps_the_filter(monkeypatch):
    # odometry increments: their clone is an exact copy of the pose when taken, and here a knot follows before
    # time tells them apart (knot 6). The run stopped with a ProcessingError; then it was the filter's, as
    # --no-smooth gives it, counted once, and said so. The clone now starts a hair apart and the pass smooths
    case = simulate_case("planar", 20.0, seed=1, gps_sigma_m=1.0, odom=OdomNoise())
    use = {"imu": {"gyro"}, "wheel": {"speed"}, "odom": {"delta"}, "gps": {"position"}}
    filt = fuse(case.inputs, FuseOptions(estimator="planar", rate_hz=20.0, use=use))
    smoothed = fuse(case.inputs, FuseOptions(estimator="planar", rate_hz=20.0, use=use, smooth=True))
    assert smoothed.smoothed and smoothed.info["smoother"]["kind"] == "rts"
    assert ate(case, smoothed) < ate(case, filt)
    monkeypatch.setattr(planar, "CLONE_JITTER", 0.0)  # an exact copy: the fallback
    monkeypatch.setattr(planar, "CLONE_JITTER_FLOOR", 0.0)
    kept = fuse(case.inputs, FuseOptions(estimator="planar", rate_hz=20.0, use=use, smooth=True))
    assert not graph_smooths(kept.info["use"], "planar")  # no accelerometer: the RTS pass was the smoother asked
    sm = kept.info["smoother"]
    assert sm["kind"] is None and sm["why"].startswith("predicted covariance singular at knot ")
    assert not kept.smoothed and f"smoother: {sm['why']}: the planar filter's trajectory kept, unsmoothed (odometry " \
        "increments, odom:delta, can do this; as poses, odom:pose, they smooth)" in kept.info["notes"]
    np.testing.assert_array_equal(kept.poses, filt.poses)
    for s in ("odom", "gps", "wheel"):
        assert kept.reports[s].updates == filt.reports[s].updates > 0
    assert ate(case, kept) < 1.0
