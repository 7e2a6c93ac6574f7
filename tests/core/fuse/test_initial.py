"""Start-up: attitude from gravity, standing detection, and what a steady turn must not be taken for."""

from __future__ import annotations

import numpy as np

from lio_cli.core.fuse.initial import without_yaw
from lio_cli.geometry import gravity_aligned_rotation
from lio_cli.geometry import so3_exp, yaw_of

ROT_TOL = 1e-12


def test_level_rotation_puts_the_specific_force_on_world_z_with_zero_yaw():
    R_true = so3_exp(np.array([0.2, -0.3, 0.0]))
    R_true = without_yaw(R_true)
    f_base = R_true.T @ np.array([0.0, 0.0, 9.81])
    R = gravity_aligned_rotation(f_base)
    np.testing.assert_allclose(R @ f_base, [0.0, 0.0, 9.81], atol=1e-12)
    np.testing.assert_allclose(yaw_of(R), 0.0, atol=ROT_TOL)
    np.testing.assert_allclose(R, R_true, atol=1e-12)


def test_level_rotation_upside_down():
    R = gravity_aligned_rotation(np.array([0.0, 0.0, -9.81]))
    np.testing.assert_allclose(R @ np.array([0.0, 0.0, -1.0]), [0.0, 0.0, 1.0], atol=ROT_TOL)


def test_without_yaw_keeps_tilt():
    R = so3_exp(np.array([0.0, 0.0, 1.2])) @ so3_exp(np.array([0.1, 0.05, 0.0]))
    Rn = without_yaw(R)
    np.testing.assert_allclose(yaw_of(Rn), 0.0, atol=ROT_TOL)
    np.testing.assert_allclose(Rn.T @ [0, 0, 1.0], R.T @ [0, 0, 1.0], atol=ROT_TOL)  # same "up" in base


def _cruising_inputs(speed_mps: float, wheels: bool, odom: bool):
    """An IMU that reads exactly as at rest (straight line at constant speed), with wheels or odometry."""
    from lio_cli.core.fuse import FuseInputs, ImuSeries, PoseSeries, WheelSeries

    t0 = 1_700_000_000 * 10**9
    st = t0 + np.arange(0, 2_000_000_001, 10_000_000, dtype=np.int64)
    n = len(st)
    imu = ImuSeries(st, np.zeros((n, 3)), np.tile([0.0, 0.0, 9.81], (n, 1)))
    x = speed_mps * (st - t0) * 1e-9
    wheel = WheelSeries(st[::5], np.column_stack([np.full(len(st[::5]), speed_mps), np.full((len(st[::5]), 2), np.nan)]),
                        np.zeros(len(st[::5]))) if wheels else None
    poses = np.repeat(np.eye(4)[None], n, axis=0)
    poses[:, 0, 3] = x
    return FuseInputs(imu=imu, wheel=wheel, odom=PoseSeries(st[::10], poses[::10]) if odom else None)


def test_constant_velocity_start_is_not_taken_for_standing_when_wheels_or_odometry_move():
    """At constant velocity the IMU reads as at rest; the wheels (or the odometry) say otherwise, and the run
    must start moving at their speed instead of pinning the velocity to zero."""
    from lio_cli.core.fuse import FuseOptions
    from lio_cli.core.fuse.initial import initial_state
    from lio_cli.core.fuse.timeline import prepare

    o = FuseOptions(estimator="ekf")
    for wheels, odom, what in ((True, False, "the wheels report 2.00 m/s"), (False, True, "the odometry moves 2.00 m/s")):
        prep = prepare(_cruising_inputs(2.0, wheels, odom), o)
        s = initial_state(prep, o.standing_window_ns, o.gravity_mps2, o.noise)
        assert not s.standing
        assert f"moving start at constant velocity ({what}; the IMU alone looks still)" in s.reason
    prep = prepare(_cruising_inputs(0.0, True, False), o)
    assert initial_state(prep, o.standing_window_ns, o.gravity_mps2, o.noise).standing  # wheels at rest: standing


def _turning_inputs(odom: bool, wheels: bool, v_mps: float = 1.0, w_radps: float = 2.0):
    """A unicycle turning from the first sample, measured exactly: the IMU (in the base) reads the
    centripetal v w beside gravity, 2 m/s^2 here, which the mean specific force takes for an 11.5 deg tilt."""
    from lio_cli.core.fuse import FuseInputs, ImuSeries, PoseSeries, WheelSeries

    t0 = 1_700_000_000 * 10**9
    st = t0 + np.arange(0, 3_000_000_001, 10_000_000, dtype=np.int64)
    n, t = len(st), (st - t0) * 1e-9
    imu = ImuSeries(st, np.tile([0.0, 0.0, w_radps], (n, 1)), np.tile([0.0, v_mps * w_radps, 9.81], (n, 1)))
    yaw = w_radps * t
    poses = np.repeat(np.eye(4)[None], n, axis=0)
    poses[:, :3, :3] = so3_exp(np.column_stack([np.zeros(n), np.zeros(n), yaw]))
    poses[:, 0, 3], poses[:, 1, 3] = v_mps / w_radps * np.sin(yaw), v_mps / w_radps * (1 - np.cos(yaw))
    wheel = WheelSeries(st[::5], np.column_stack([np.full(len(st[::5]), v_mps), np.zeros((len(st[::5]), 2))]),
                        np.full(len(st[::5]), w_radps)) if wheels else None
    return FuseInputs(imu=imu, wheel=wheel, odom=PoseSeries(st[::10], poses[::10]) if odom else None)


TILT_TOL_RAD = np.radians(0.1)  # exact measurements: what remains is the alignment's discretisation


def _tilt_rad(R: np.ndarray) -> float:
    return float(np.arccos(np.clip((R.T @ [0.0, 0.0, 1.0])[2], -1.0, 1.0)))


def test_moving_start_takes_gravity_from_the_odometry_or_the_wheels_not_the_turn():
    """Turning at the first sample: the odometry poses (or the wheels with the gyro) tell the centripetal
    acceleration from gravity (``bootstrap.align``), so the start is level, not tilted by atan(2 / 9.81) =
    11.5 deg as the mean specific force had it, and the velocity is the odometry's (1 m/s forward)."""
    from lio_cli.core.fuse import FuseOptions
    from lio_cli.core.fuse.initial import initial_state
    from lio_cli.core.fuse.timeline import prepare

    o = FuseOptions(estimator="ekf")
    for odom, wheels, source in ((True, False, "odometry"), (False, True, "wheels"), (True, True, "odometry")):
        s = initial_state(prepare(_turning_inputs(odom, wheels), o), o.standing_window_ns, o.gravity_mps2, o.noise)
        assert not s.standing
        assert _tilt_rad(s.R) < TILT_TOL_RAD  # was 0.201 rad
        np.testing.assert_allclose(s.R.T @ s.v, [1.0, 0.0, 0.0], atol=0.02)  # base axes; was 0 (wheels: 1)
        assert f"roll, pitch and velocity aligned with the {source} over" in s.reason


def test_moving_start_without_odometry_or_wheels_says_its_tilt_is_the_motions():
    """With the IMU alone nothing tells the turn from gravity: the start keeps the mean specific force, and
    the reason says so instead of silently tilting the world."""
    from lio_cli.core.fuse import FuseOptions
    from lio_cli.core.fuse.initial import initial_state
    from lio_cli.core.fuse.timeline import prepare

    o = FuseOptions(estimator="ekf")
    s = initial_state(prepare(_turning_inputs(False, False), o), o.standing_window_ns, o.gravity_mps2, o.noise)
    np.testing.assert_allclose(_tilt_rad(s.R), np.arctan2(2.0, 9.81), atol=1e-6)
    assert ("roll and pitch from the mean specific force over 0.20 s, tilted by whatever the motion accelerated "
            "(no odometry or wheels cover the start)") in s.reason
