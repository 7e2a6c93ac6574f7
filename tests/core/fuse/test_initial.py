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

    o = FuseOptions()
    for wheels, odom, what in ((True, False, "the wheels report 2.00 m/s"), (False, True, "the odometry moves 2.00 m/s")):
        prep = prepare(_cruising_inputs(2.0, wheels, odom), o)
        s = initial_state(prep, o.standing_window_ns, o.gravity_mps2, o.noise)
        assert not s.standing
        assert f"moving start at constant velocity ({what}; the IMU alone looks still)" in s.reason
    prep = prepare(_cruising_inputs(0.0, True, False), o)
    assert initial_state(prep, o.standing_window_ns, o.gravity_mps2, o.noise).standing  # wheels at rest: standing
