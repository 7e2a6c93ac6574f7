"""The planar filter's track on a swaying car: it turns with the heading's rate (the base z axis is not the
vertical when the body rolls and pitches), and its poses are those of their stamps (its step's left sum put them
half a gyro period earlier)."""

from __future__ import annotations

import numpy as np

from lio_cli.core.fuse import FuseOptions, fuse, level, rts_planar
from lio_cli.core.fuse.level import heading_rate_offset, up_directions
from lio_cli.simulation.fusion_case import simulate_case

from .test_level import _synthetic_drive


def _horizontal_error(case, res) -> float:
    """RMS of the result's x, y against the truth after the best 2D rotation and shift, m."""
    i = np.searchsorted(case.truth_stamps_ns, res.stamps_ns).clip(0, len(case.truth_stamps_ns) - 1)
    P, Q = res.poses[:, :2, 3], case.truth_poses[i][:, :2, 3]
    P, Q = P - P.mean(axis=0), Q - Q.mean(axis=0)
    U, _, Vt = np.linalg.svd(P.T @ Q)
    d = np.diag([1.0, np.sign(np.linalg.det(U @ Vt))])
    return float(np.sqrt(np.mean(np.sum((P @ (U @ d @ Vt) - Q) ** 2, axis=1))))


def test_the_heading_rate_comes_from_the_tilted_gyro():
    # the synthetic drive's heading rate is known: the base z rate is off it by the sway's cross terms
    prep, _ = _synthetic_drive(0.0, 0.0)
    prep.imu_w_b[:, 1] += 0.01  # the pitch rate biased: times the roll, a yaw bias of 2.9e-5 rad/s if kept
    yaw_rate = 0.3 * np.sin(2 * np.pi * np.arange(0.0, 60.0, 0.005) / 11)
    base_z = prep.imu_w_b[:, 2] - 0.001 - yaw_rate  # the z bias taken out
    heading = base_z + heading_rate_offset(prep, up_directions(prep))
    assert np.std(heading) < 0.5 * np.std(base_z), (np.std(heading), np.std(base_z))  # 3.4e-4 against 7.4e-4
    assert abs(np.mean(heading)) < 1e-5, np.mean(heading)  # 4.8e-6


def test_a_swaying_car_turns_about_the_vertical(monkeypatch):
    # a car's sway turned the base z axis off the vertical: its rate integrated as the heading bent the path
    case = simulate_case("drive", 30.0, seed=4, wheel_errors=False)
    res = fuse(case.inputs, FuseOptions(smooth=True, rate_hz=50.0))
    assert res.estimator == "planar"
    monkeypatch.setattr(level, "heading_rate_offset", lambda prep, up: np.zeros(len(up)))
    base_z = fuse(case.inputs, FuseOptions(smooth=True, rate_hz=50.0))
    err, err_base_z = _horizontal_error(case, res), _horizontal_error(case, base_z)
    assert err < 0.005 and err < 0.6 * err_base_z, (err, err_base_z)  # measured 0.0030 against 0.0084


def test_the_filter_s_pose_is_its_stamp_s_not_half_a_gyro_period_before(monkeypatch):
    # the model's step takes the rates at its start: a left sum, the pose of half a gyro period before the knot
    # (2.5 ms at 200 Hz, 1.9 cm along a car's track at 7.5 m/s); the output is moved on by that
    case = simulate_case("drive", 20.0, seed=4, wheel_errors=False)
    opts = FuseOptions(rate_hz=50.0, estimator="planar")
    advanced = _horizontal_error(case, fuse(case.inputs, opts))
    monkeypatch.setattr(rts_planar, "advanced", lambda x, lag_s: x)
    lagging = _horizontal_error(case, fuse(case.inputs, opts))
    assert advanced < 0.004 and advanced < 0.5 * lagging, (advanced, lagging)  # measured 0.0023 against 0.0087
