"""``plots.fuse``: the wheels dead-reckoned from the fused start, and the two PNGs of ``--plot``, drawn from
anything shaped like a fuse run (the plots know no job)."""

from types import SimpleNamespace

import numpy as np
import pytest

from lio_cli.core.fuse.inputs import ImuSeries, WheelSeries
from lio_cli.errors import InputError
from lio_cli.geometry import make_pose, so3_exp
from lio_cli.model.trajectory import Trajectory
from lio_cli.plots.fuse import PLOT_FILES, wheel_dead_reckoning, write_plots

NS = 1_000_000_000
RATE_HZ = 50
EULER_TOL_M = 0.05  # one Euler step per 20 ms on a 1 m radius circle drifts a few mm per turn
PNG = b"\x89PNG\r\n\x1a\n"


def _run(duration_s=2.0, v=1.0, w=0.0, yaw0=0.0, wheel_yaw=True, imu=False):
    """A fused run driving at ``v`` m/s and ``w`` rad/s from the origin heading ``yaw0``, with its wheels."""
    n = int(duration_s * RATE_HZ) + 1
    stamps = np.arange(n, dtype=np.int64) * (NS // RATE_HZ)
    t = stamps * 1e-9
    yaw = yaw0 + w * t
    if w:
        xy = np.column_stack([np.sin(yaw) - np.sin(yaw0), np.cos(yaw0) - np.cos(yaw)]) * (v / w)
    else:
        xy = np.column_stack([np.cos(yaw0) * v * t, np.sin(yaw0) * v * t])
    poses = np.stack([make_pose(so3_exp(np.array([0.0, 0.0, a])), np.array([x, y, 0.0])) for a, (x, y) in zip(yaw, xy)])
    wheel = WheelSeries(stamps, np.tile([v, 0.0, np.nan], (n, 1)), np.full(n, w if wheel_yaw else np.nan))
    gyro = ImuSeries(stamps, np.tile([0.0, 0.0, w], (n, 1)), np.tile([0.0, 0.0, 9.81], (n, 1))) if imu else None
    inputs = SimpleNamespace(wheel=wheel, imu=gyro, odom=None, gps=None)
    run = SimpleNamespace(trajectory=Trajectory(stamps, poses, "fused"), velocities_mps=None,
                          config=SimpleNamespace(estimator="ekf", smooth=False), sources=SimpleNamespace(inputs=inputs))
    return run, xy


def test_straight_wheels_retrace_the_fused_line_from_its_start_and_heading():
    run, xy = _run(v=1.5, yaw0=np.pi / 3)
    dr, label = wheel_dead_reckoning(run)
    assert label == "wheels dead-reckoned"
    np.testing.assert_allclose(dr, xy, atol=1e-9)


def test_wheels_without_a_yaw_rate_turn_with_the_gyro_and_say_so():
    run, xy = _run(duration_s=np.pi, w=1.0, wheel_yaw=False, imu=True)
    dr, label = wheel_dead_reckoning(run)
    assert label == "wheels dead-reckoned (yaw rate from the gyro)"
    assert np.max(np.linalg.norm(dr - xy, axis=1)) < EULER_TOL_M


def test_no_wheels_or_a_single_message_draw_no_dead_reckoning():
    run, _ = _run()
    run.sources.inputs.wheel = None
    assert wheel_dead_reckoning(run) is None
    run, _ = _run(duration_s=0.0)
    assert wheel_dead_reckoning(run) is None


def test_write_plots_writes_both_pngs_and_refuses_to_overwrite(tmp_path):
    run, _ = _run(duration_s=np.pi, w=1.0, imu=True)
    paths = write_plots(run, tmp_path)
    assert [p.name for p in paths] == list(PLOT_FILES)
    assert all(p.read_bytes()[:8] == PNG for p in paths)
    with pytest.raises(InputError):
        write_plots(run, tmp_path)
    assert [p.name for p in write_plots(run, tmp_path, force=True)] == list(PLOT_FILES)
