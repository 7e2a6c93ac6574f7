"""``plots.trajectories`` and ``plots.map``: what each picture draws (axis labels, legend, the numbers on its lines)
and the PNGs written (decoded, of the size the figure asks)."""

import matplotlib.image as mpimg
import numpy as np
import pytest

from lio_cli.errors import InputError
from lio_cli.geometry import make_pose, so3_exp
from lio_cli.model.trajectory import Trajectory
from lio_cli.plots.map import SIZE_IN, density_grid, map_figure, preview_path, write_map_preview
from lio_cli.plots.style import DPI
from lio_cli.plots.trajectories import (PLOT_FILES, SIZES_IN, break_at_wraps, rpy_figure, speed_figure, speeds,
                                        time_origin, top_view_figure, wrapped_degrees, write_trajectory_plots,
                                        xyz_figure)

NS = 1_000_000_000
T0_NS = 1_700_000_000 * NS
RADIUS_M, OMEGA_RADPS = 4.0, 0.5  # a circle at 2 m/s


def _rot(roll, pitch, yaw):
    return so3_exp(np.array([0.0, 0.0, yaw])) @ so3_exp(np.array([0.0, pitch, 0.0])) @ so3_exp(np.array([roll, 0.0, 0.0]))


def _circle(name="a", n=200, dt_ns=NS // 10, t0_ns=T0_NS, shift=(0.0, 0.0, 0.0)):
    t = np.arange(n) * dt_ns * 1e-9
    a = OMEGA_RADPS * t
    xyz = np.column_stack([RADIUS_M * np.cos(a), RADIUS_M * np.sin(a), 0.2 * t]) + shift
    poses = np.stack([make_pose(_rot(0.1, -0.2, yaw + np.pi / 2), p) for yaw, p in zip(a, xyz)])
    return Trajectory(t0_ns + np.arange(n, dtype=np.int64) * dt_ns, poses, name)


def _labels(fig):
    return [(ax.get_xlabel(), ax.get_ylabel()) for ax in fig.axes]


def test_each_picture_labels_its_axes_and_names_every_trajectory_in_the_legend():
    tracks = [_circle("gt.tum"), _circle("odom.tum", shift=(0.3, 0, 0))]
    top = top_view_figure(tracks)
    assert _labels(top) == [("x [m]", "y [m]")]
    assert [t.get_text() for t in top.axes[0].get_legend().get_texts()] == ["gt.tum", "odom.tum"]
    assert top.axes[0].get_aspect() == 1.0  # equal axes
    assert [y for _, y in _labels(xyz_figure(tracks))] == ["x [m]", "y [m]", "z [m]"]
    assert [y for _, y in _labels(rpy_figure(tracks))] == ["roll [deg]", "pitch [deg]", "yaw [deg]"]
    assert _labels(speed_figure(tracks)) == [("time since the start [s]", "speed [m/s]")]
    assert _labels(xyz_figure(tracks))[-1][0] == "time since the start [s]"


def test_the_lines_carry_the_trajectories_numbers():
    t = _circle()
    x_line = xyz_figure([t]).axes[0].lines[0]
    np.testing.assert_allclose(x_line.get_xdata(), (t.stamps_ns - T0_NS) * 1e-9)
    np.testing.assert_allclose(x_line.get_ydata(), t.positions[:, 0])
    roll, pitch, yaw = (ax.lines[0] for ax in rpy_figure([t]).axes)
    np.testing.assert_allclose(roll.get_ydata(), np.degrees(0.1), atol=1e-9)
    np.testing.assert_allclose(pitch.get_ydata(), np.degrees(-0.2), atol=1e-9)
    secs = (t.stamps_ns - T0_NS) * 1e-9
    expected_yaw = (np.degrees(OMEGA_RADPS * secs + np.pi / 2) + 180) % 360 - 180  # 90 deg on, 573 deg turned
    drawn = np.isfinite(yaw.get_ydata())
    np.testing.assert_allclose(yaw.get_ydata()[drawn], expected_yaw, atol=1e-9)
    np.testing.assert_allclose(yaw.get_xdata()[drawn], secs)
    assert (~drawn).sum() == 2  # the two wraps from +180 to -180 are no lines across the panel
    _, v = speeds(t)
    chord = 2 * RADIUS_M * np.sin(OMEGA_RADPS * 0.1 / 2)  # straight between poses 0.1 s apart, plus the climb
    np.testing.assert_allclose(v, np.hypot(chord, 0.02) / 0.1, rtol=1e-9)


def test_angle_lines_break_only_where_they_wrap():
    deg = wrapped_degrees(np.radians([170, 179, 181, 170, 100, -60]))
    np.testing.assert_allclose(deg, [170, 179, -179, 170, 100, -60])
    x, y = break_at_wraps(np.arange(6.0), deg)
    np.testing.assert_allclose(x, [0, 1, np.nan, 2, np.nan, 3, 4, 5])
    np.testing.assert_allclose(y, [170, 179, np.nan, -179, np.nan, 170, 100, -60])  # 160 deg: a real turn


def test_time_runs_from_the_earliest_start_unless_the_trajectories_do_not_overlap():
    a, b = _circle(), _circle(t0_ns=T0_NS + 3 * NS)
    assert time_origin([a, b]) == ([T0_NS, T0_NS], "time since the start [s]")
    far = _circle(t0_ns=5 * NS)  # a relative clock
    starts, label = time_origin([a, far])
    assert starts == [T0_NS, 5 * NS] and "each trajectory's start" in label


def test_position_only_trajectories_have_no_orientation_line():
    gps = _circle("fix")
    gps.kind = "gps"
    fig = rpy_figure([_circle("odom"), gps])
    assert [len(ax.lines) for ax in fig.axes] == [1, 1, 1]


def test_write_trajectory_plots_writes_the_four_pngs_at_their_size_and_refuses_to_overwrite(tmp_path):
    paths = write_trajectory_plots([_circle("a"), _circle("b", shift=(0, 1, 0))], tmp_path / "plots")
    assert [p.name for p in paths] == list(PLOT_FILES)
    for p in paths:
        w, h = SIZES_IN[p.name]
        assert mpimg.imread(p).shape[:2] == (round(h * DPI), round(w * DPI))
    with pytest.raises(InputError, match="already exists; pass --force"):
        write_trajectory_plots([_circle()], tmp_path / "plots")
    write_trajectory_plots([_circle()], tmp_path / "plots", force=True)


def test_density_grid_counts_every_point_once_in_its_cell():
    rng = np.random.default_rng(0)
    pts = np.vstack([rng.uniform([0, 0, 0], [10, 5, 3], (5000, 3)), [[np.nan, 0, 0]]])
    counts, extent, cell = density_grid(pts, 0.5)
    assert counts.sum() == 5000 and cell == 0.5
    assert counts.shape == (round((extent[3] - extent[2]) / cell), round((extent[1] - extent[0]) / cell))
    x0, _, y0, _ = extent
    i, j = int((2.2 - y0) // cell), int((7.3 - x0) // cell)
    inside = ((pts[:, 0] >= x0 + j * cell) & (pts[:, 0] < x0 + (j + 1) * cell)
              & (pts[:, 1] >= y0 + i * cell) & (pts[:, 1] < y0 + (i + 1) * cell))
    assert counts[i, j] == inside.sum()
    big = density_grid(rng.uniform(0, 1000, (100, 3)), 0.1)[0]
    assert max(big.shape) <= 800  # long maps get coarser cells, not huge images


def test_map_preview_png_labels_and_trajectory(tmp_path):
    pts = np.random.default_rng(1).uniform(-5, 5, (2000, 3))
    fig = map_figure(pts, 0.1, _circle("odom"))
    ax = fig.axes[0]
    assert (ax.get_xlabel(), ax.get_ylabel()) == ("x [m]", "y [m]")
    assert "2000 points, 0.1 m voxels" in ax.get_title()
    np.testing.assert_allclose(ax.lines[0].get_xdata(), _circle().positions[:, 0])
    path = write_map_preview(pts, preview_path(tmp_path / "run.ply"), voxel_m=0.1)
    assert path == tmp_path / "run.png"
    assert mpimg.imread(path).shape[:2] == (round(SIZE_IN[1] * DPI), round(SIZE_IN[0] * DPI))
    write_map_preview(np.zeros((0, 3)), tmp_path / "empty.png")  # an empty map still gives a picture
