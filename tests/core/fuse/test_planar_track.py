"""The planar filter's track on a swaying car: it turns with the heading's rate (the base z axis is not the
vertical when the body rolls and pitches), and its poses are those of their stamps (its step's left sum put them
half a gyro period earlier); beside odometry its increments turn it as tight as their scatter shows."""

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


def _yaw_error_deg(case, res) -> float:
    """RMS of the heading's error against the truth, its start's taken out, deg."""
    from lio_cli.geometry import interpolate_poses, yaw_of

    truth = interpolate_poses(case.truth_stamps_ns, case.truth_poses, res.stamps_ns)
    d = np.unwrap(yaw_of(res.poses[:, :3, :3]) - yaw_of(truth[:, :3, :3]))
    return float(np.degrees(np.sqrt(np.mean((d - d[0]) ** 2))))


def test_odometry_increments_turn_the_planar_filter_as_tight_as_their_scatter(monkeypatch):
    # odometry whose heading holds (white 0.2 mrad per pose, no drift) in a file without covariances: at the
    # default 20 mrad per pose its increments held nothing; their scatter about the gyro's says what they are worth
    from dataclasses import replace

    from lio_cli.core.fuse.graph import odom_spin
    from lio_cli.simulation.fusion_case import OdomNoise

    case = simulate_case("drive", 30.0, seed=2, wheel_errors=False,
                         odom=OdomNoise(position_sigma_m=0.005, rotation_sigma_rad=2e-4, drift_yaw_rw=0.0))
    od = case.inputs.odom
    inputs = replace(case.inputs, odom=replace(od, rotation_sigma_rad=np.full(len(od), 0.02),
                                               position_sigma_m=np.full(len(od), 0.1)))
    opts = FuseOptions(smooth=True, rate_hz=50.0, estimator="planar",
                       use={"imu": {"gyro", "accel"}, "wheel": {"speed"}, "odom": {"delta"}})
    tight = fuse(inputs, opts)
    assert tight.info["smoother"]["kind"] == "rts"  # the clone a hair apart: no singular prediction
    monkeypatch.setattr(odom_spin, "increment_sigma", lambda prep, idx: None)
    loose = fuse(inputs, opts)
    assert _yaw_error_deg(case, tight) < 0.5 * _yaw_error_deg(case, loose), (  # measured 0.011 against 0.042
        _yaw_error_deg(case, tight), _yaw_error_deg(case, loose))
