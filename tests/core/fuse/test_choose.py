"""The default estimator chosen from the data: planar for a wheeled robot near a plane, the 3D EKF for a
handheld log and for a robot that climbs; the reason said; an explicit estimator kept; a moving start."""

from __future__ import annotations

import numpy as np

from lio_cli.core.fuse import FuseInputs, FuseOptions, ImuSeries, WheelSeries, fuse
from lio_cli.evaluation import EvalOptions, Trajectory, evaluate
from lio_cli.geometry import interpolate_poses, so3_exp
from lio_cli.simulation.fusion_case import START_NS, OdomNoise, simulate_case

NS = 1_000_000_000
WHEEL_DR_RATIO = 0.5  # planar moving start: fused ATE vs wheel dead reckoning (measured 0.24)
ODOM_RATIO = 1.0  # handheld: fused ATE vs the odometry input's (measured 0.69; planar there: 3.6)


def _ate(case, stamps, poses) -> float:
    ref = Trajectory(case.truth_stamps_ns, case.truth_poses, "gt")
    return evaluate(ref, Trajectory(stamps, poses, "est"), EvalOptions(align="se3")).stats["ape"]["trans"]["rmse"]


def _from(series, t_ns: int):
    """The series from ``t_ns`` on: a log that starts in motion."""
    keep = series.stamps_ns >= t_ns
    return type(series)(**{k: v[keep] if isinstance(v, np.ndarray) and v.shape[:1] == keep.shape else v
                           for k, v in vars(series).items()})


def _moving(case, after_s: float) -> FuseInputs:
    t = START_NS + int(after_s * NS)
    return FuseInputs(*(None if s is None else _from(s, t) for s in
                        (case.inputs.imu, case.inputs.wheel, case.inputs.odom, case.inputs.gps)))


def test_a_ground_robot_starting_in_motion_gets_the_planar_filter_and_beats_its_wheels():
    case = simulate_case("planar", 30.0, seed=1)  # wheel radius and baseline errors and a slip
    inputs = _moving(case, 3.0)
    res = fuse(inputs, FuseOptions(rate_hz=50.0))
    assert res.estimator == "planar"
    assert res.info["estimator_reason"].startswith("a wheeled robot near a plane: tilt ")
    assert res.info["estimator_evidence"]["tilt_p95_deg"] < 2.0 and res.info["estimator_evidence"]["climb_m"] < 0.2
    keep = case.inputs.wheel.stamps_ns >= inputs.wheel.stamps_ns[0]
    dr = _ate(case, case.inputs.wheel.stamps_ns[keep], case.wheel_dead_reckoning[keep])
    assert _ate(case, res.stamps_ns, res.poses) < WHEEL_DR_RATIO * dr
    assert "moving start" in res.info["start"] and "velocity from the first wheel message" in res.info["start"]


def test_a_handheld_log_gets_the_3d_filter():
    case = simulate_case("handheld", 20.0, seed=1, wheels=False, odom=OdomNoise())
    inputs = _moving(case, 3.0)
    res = fuse(inputs, FuseOptions(rate_hz=50.0))
    assert res.estimator == "ekf"
    assert res.info["estimator_reason"] == "no wheel odometry: the motion is taken as 3D (handheld, drone)"
    odom = _ate(case, inputs.odom.stamps_ns, inputs.odom.poses)
    assert _ate(case, res.stamps_ns, res.poses) < ODOM_RATIO * odom
    planar = fuse(inputs, FuseOptions(rate_hz=50.0, estimator="planar"))
    assert planar.info["estimator_reason"] == ("given with --estimator, where the data ask for the 3D filter: no "
                                               "wheel odometry: the motion is taken as 3D (handheld, drone)")
    assert _ate(case, planar.stamps_ns, planar.poses) > 2.0 * _ate(case, res.stamps_ns, res.poses)


def _ramp_robot(amplitude_m: float) -> FuseInputs:
    """A robot driving straight at 1 m/s over a road z = A sin(2 pi x / 20 m), IMU and wheels exact."""
    rate, dur, v = 100.0, 40.0, 1.0
    t = np.arange(int(dur * rate) + 1) / rate
    k = 2 * np.pi / 20.0
    x = v * t  # close enough: the arc length differs from x by < 1 % at these slopes
    pitch = np.arctan(amplitude_m * k * np.cos(k * x))
    pitch_rate = np.gradient(pitch, t)
    vel_w = np.column_stack([v * np.cos(pitch), np.zeros_like(t), v * np.sin(pitch)])
    acc_w = np.gradient(vel_w, t, axis=0) + [0.0, 0.0, 9.81]
    R = so3_exp(np.column_stack([np.zeros_like(t), -pitch, np.zeros_like(t)]))  # nose up: negative about y
    f_b = np.einsum("nji,nj->ni", R, acc_w)
    gyro = np.column_stack([np.zeros_like(t), -pitch_rate, np.zeros_like(t)])
    st = START_NS + (t * NS).astype(np.int64)
    imu = ImuSeries(st, gyro, f_b)
    wheel = WheelSeries(st[::2], np.column_stack([np.full(len(st[::2]), v), np.full((len(st[::2]), 2), np.nan)]),
                        np.zeros(len(st[::2])))
    return FuseInputs(imu=imu, wheel=wheel)


def test_a_robot_that_climbs_gets_the_3d_filter_and_a_flat_one_the_planar():
    hills = fuse(_ramp_robot(1.0), FuseOptions(rate_hz=10.0))  # 2 m up and down, 17 deg slopes
    assert hills.estimator == "ekf"
    assert hills.info["estimator_reason"].startswith("the ground tilts the robot by ")
    bumps = fuse(_ramp_robot(0.3), FuseOptions(rate_hz=10.0))  # 5 deg slopes, 0.6 m up and down
    assert bumps.estimator == "ekf" and bumps.info["estimator_reason"].startswith("wheels and IMU climb 0.6")
    flat = fuse(_ramp_robot(0.0), FuseOptions(rate_hz=10.0))
    assert flat.estimator == "planar"
    assert fuse(_ramp_robot(0.0), FuseOptions(rate_hz=10.0, estimator="ekf")).estimator == "ekf"


def test_the_planar_filter_given_where_the_data_ask_for_3d_is_run_and_told():
    hills = fuse(_ramp_robot(1.0), FuseOptions(rate_hz=10.0, estimator="planar"))
    assert hills.estimator == "planar"
    assert hills.info["estimator_reason"].startswith("given with --estimator, where the data ask for the 3D filter: "
                                                     "the ground tilts the robot by "), hills.info["estimator_reason"]
    flat = fuse(_ramp_robot(0.0), FuseOptions(rate_hz=10.0, estimator="planar"))
    assert flat.info["estimator_reason"] == "given with --estimator"


def test_odometry_poses_beside_an_accelerometer_get_the_3d_filter_and_a_smooth_high_rate_output():
    """A car with LiDAR-like odometry and wheels: the planar filter's 200 Hz output was noisier over 0.05 s
    (0.044 m) than the odometry interpolated (0.025 m); the 3D one's is 0.007 m."""
    case = simulate_case("drive", 20.0, seed=2, odom=OdomNoise())
    inputs = _moving(case, 3.0)
    res = fuse(inputs, FuseOptions(rate_hz=200.0))
    assert res.estimator == "ekf" and res.info["estimator_reason"].startswith("odometry poses and an accelerometer")
    od = inputs.odom
    st = np.arange(od.stamps_ns[0], od.stamps_ns[-1], 5_000_000)
    interpolated = _rpe_005(case, st, interpolate_poses(od.stamps_ns, od.poses, st))
    assert _rpe_005(case, res.stamps_ns, res.poses) < 0.5 * interpolated
    assert _ate(case, res.stamps_ns, res.poses) <= _ate(case, od.stamps_ns, od.poses)


def _rpe_005(case, stamps, poses) -> float:
    ref = Trajectory(case.truth_stamps_ns, case.truth_poses, "gt")
    opts = EvalOptions(align="se3", delta=0.05, delta_unit="s", max_diff_ns=1_000_000)
    return evaluate(ref, Trajectory(stamps, poses, "est"), opts).stats["rpe"]["trans"]["rmse"]


def test_odometry_the_wheels_agree_with_gets_the_planar_filter_beside_it():
    """The same car with exact wheels: they agree with the odometry (its path 1.0012x their distance, +- 0.0025),
    so the data cannot tell which is off, and the planar filter keeps the wheels' speed, the odometry as
    increments: 0.0073 m against the 3D filter's 0.0198 and the odometry's 0.039."""
    case = simulate_case("drive", 20.0, seed=2, odom=OdomNoise(), wheel_errors=False)
    inputs = _moving(case, 3.0)
    res = fuse(inputs, FuseOptions(rate_hz=200.0, smooth=True))
    assert res.estimator == "planar" and res.info["use"]["odom"] == ["delta"]
    assert "; beside the odometry, the wheels agreeing with it (the odometry's path 1.00" in res.info["estimator_reason"]
    assert res.info["estimator_evidence"]["wheels_agree_with_odometry"]
    ekf = fuse(inputs, FuseOptions(rate_hz=200.0, smooth=True, estimator="ekf"))
    od = inputs.odom
    st = np.arange(od.stamps_ns[0], od.stamps_ns[-1], 5_000_000)
    interpolated = _rpe_005(case, st, interpolate_poses(od.stamps_ns, od.poses, st))
    assert _rpe_005(case, res.stamps_ns, res.poses) < 0.5 * interpolated
    fused = _ate(case, res.stamps_ns, res.poses)
    assert fused < 0.5 * _ate(case, ekf.stamps_ns, ekf.poses) and fused < 0.25 * _ate(case, od.stamps_ns, od.poses)


def test_without_an_accelerometer_nothing_weighs_the_wheels_and_the_odometry_stays_poses():
    # planar on the odometry's climb alone: increments beside wheels nobody checked went 0.22 -> 5.4 m
    case = simulate_case("drive", 20.0, seed=4, odom=OdomNoise())  # wheel radius and baseline errors
    res = fuse(FuseInputs(wheel=case.inputs.wheel, odom=case.inputs.odom), FuseOptions(smooth=True))
    assert res.estimator == "planar" and res.info["use"]["odom"] == ["pose"]
    assert _ate(case, res.stamps_ns, res.poses) < 0.5
