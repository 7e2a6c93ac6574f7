"""Wheel odometry scales against LiDAR odometry, with the simulator's wheel errors and slip as truth."""

import re

import numpy as np
import pytest

from lio_cli.core.calibration.wheel import estimate_wheel_scales
from lio_cli.errors import InputError

NS = 1_000_000_000
SCALE_REL_TOL = 0.003  # the goal
RADIUS_TOL_M = 0.0005
BASELINE_TOL_M = 0.003


def _truth(d):
    w = d.wheel_spec
    s_v = 0.5 * (w.radius_scale_left + w.radius_scale_right)
    return s_v, s_v / w.baseline_scale


def _run(d, **kw):
    return estimate_wheel_scales(d.wheel.stamps_ns, d.wheel.linear_mps, d.wheel.angular_radps, d.lidar_stamps_ns,
                                 d.T_world_lidar, T_base_traj=d.T_base_lidar, **kw)


def test_scales_radius_and_baseline_with_the_slip_left_out(planar):
    w = planar.wheel_spec
    r = _run(planar, radius_m=w.radius_m, baseline_m=w.baseline_m)
    s_v, s_w = _truth(planar)
    assert r.speed_scale == pytest.approx(s_v, rel=SCALE_REL_TOL)
    assert r.yaw_rate_scale == pytest.approx(s_w, rel=SCALE_REL_TOL)
    assert r.radius_m == pytest.approx(w.radius_m * s_v, abs=RADIUS_TOL_M)
    assert r.baseline_m == pytest.approx(w.baseline_m * w.baseline_scale, abs=BASELINE_TOL_M)
    assert r.radius_left_m == pytest.approx(w.radius_m * w.radius_scale_left, abs=RADIUS_TOL_M)
    assert r.radius_right_m == pytest.approx(w.radius_m * w.radius_scale_right, abs=RADIUS_TOL_M)
    # the slip window (20-23 s, raised-cosine edges) is found and nothing else
    assert len(r.slip_ns) == 1
    a, b = ((np.array(r.slip_ns[0]) - planar.wheel.stamps_ns[0]) / NS)
    assert 19.0 <= a <= 20.5 and 22.5 <= b <= 24.0
    assert r.notes == (f"wheel slip (or a bad registration) at {a:.1f}-{b:.1f} s after the first wheel stamp: left out",)


def test_without_nominal_values_only_the_scales_come_out(planar):
    r = _run(planar)
    s_v, s_w = _truth(planar)
    assert r.speed_scale == pytest.approx(s_v, rel=SCALE_REL_TOL)
    assert r.yaw_rate_scale == pytest.approx(s_w, rel=SCALE_REL_TOL)
    assert (r.radius_m, r.baseline_m, r.radius_left_m, r.radius_right_m) == (None, None, None, None)
    assert r.notes[0] == "no nominal baseline: the small speed error of unequal wheels while turning is not modelled"


def test_a_still_platform_is_refused(planar):
    T = np.repeat(planar.T_world_lidar[:1], len(planar.lidar_stamps_ns), axis=0)
    msg = ("wheel scales: the platform moved 0.0 m while wheel odometry ran; drive at least 2 m (better tens of metres, "
           "with turns both ways)")
    with pytest.raises(InputError, match=re.escape(msg)):
        estimate_wheel_scales(planar.wheel.stamps_ns, planar.wheel.linear_mps, planar.wheel.angular_radps,
                              planar.lidar_stamps_ns, T)


def test_disjoint_clocks_are_refused(planar):
    msg = ("wheel odometry and trajectory share 0 poses: too little overlap for windows of 1 s (are they on the same "
           "clock?)")
    with pytest.raises(InputError, match=re.escape(msg)):
        estimate_wheel_scales(planar.wheel.stamps_ns + 1000 * NS, planar.wheel.linear_mps, planar.wheel.angular_radps,
                              planar.lidar_stamps_ns, planar.T_world_lidar)


def test_a_trajectory_that_does_not_see_the_distance_is_refused(planar):
    """A corridor along which the LiDAR cannot see the platform move: its path a fraction of the wheels' (the
    scales came out 0.02 and -0.016 on `lio simulate corridor`). Refused, not written as a calibration."""
    poses = planar.T_world_lidar.copy()
    poses[:, :3, 3] *= 0.2
    with pytest.raises(InputError, match=r"^the wheels and the LiDAR trajectory disagree about the motion itself "
                                         r"\(speed scale 0\.2, yaw-rate scale 0\.9\d+\): the LiDAR did not see"):
        estimate_wheel_scales(planar.wheel.stamps_ns, planar.wheel.linear_mps, planar.wheel.angular_radps,
                              planar.lidar_stamps_ns, poses, T_base_traj=planar.T_base_lidar)


def test_badly_registered_poses_are_bridged_not_taken_for_slip(planar):
    """A pose registered 25 cm off throws out both windows that share it, by opposite amounts. Left out as slip,
    one of them could stay in, uncancelled, and bias the speed scale; bridged (the windows on either side joined
    into one that skips the pose) the slip stays the only window left out."""
    poses = planar.T_world_lidar.copy()
    rows = [50, 80, 140, 260, 330, 370]  # window ends (1 s of the 10 Hz trajectory), away from the slip
    fwd = poses[rows, :3, 0]
    poses[rows, :3, 3] += 0.25 * np.where(np.arange(len(rows)) % 2 == 0, 1.0, -1.0)[:, None] * fwd
    w = planar.wheel_spec
    r = estimate_wheel_scales(planar.wheel.stamps_ns, planar.wheel.linear_mps, planar.wheel.angular_radps,
                              planar.lidar_stamps_ns, poses, T_base_traj=planar.T_base_lidar, radius_m=w.radius_m,
                              baseline_m=w.baseline_m)
    s_v, s_w = _truth(planar)
    assert r.bridged == len(rows)
    assert len(r.slip_ns) == 1
    a, b = ((np.array(r.slip_ns[0]) - planar.wheel.stamps_ns[0]) / NS)
    assert 19.0 <= a <= 20.5 and 22.5 <= b <= 24.0
    assert r.speed_scale == pytest.approx(s_v, rel=SCALE_REL_TOL)
    assert r.yaw_rate_scale == pytest.approx(s_w, rel=SCALE_REL_TOL)
