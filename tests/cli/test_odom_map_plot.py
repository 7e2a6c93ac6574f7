"""``lio odom --map`` and ``--plot`` on a simulated walk with exact ground truth: the map's points lie on the
simulated office's surfaces in the trajectory's frame, one per voxel; the pictures decode; bad requests stop
before the run with one line."""

import json

import matplotlib.image as mpimg
import numpy as np
import pytest

from lio_cli.cli.app import main
from lio_cli.core.deskew.voxel_map import voxel_keys
from lio_cli.geometry import interpolate_poses, inv_pose, make_pose, so3_exp
from lio_cli.io.files.point_clouds import read_point_map
from lio_cli.io.files.trajectory import read_tum
from lio_cli.plots.map import SIZE_IN
from lio_cli.plots.style import DPI
from lio_cli.plots.trajectories import PLOT_FILES, SIZES_IN
from lio_cli.simulation.run import simulate
from lio_cli.simulation.scenarios import build_scenario

VOXEL_M = 0.1
NEAR_PLANE_M = 0.3  # points this close to the floor or ceiling plane are on it
PLANE_P95_M = 0.05  # ...and lie this close to it in the right frame
WORLD_MARGIN_M = 0.3  # odometry drift over 3 s and a voxel


@pytest.fixture(scope="module")
def run(tmp_path_factory):
    root = tmp_path_factory.mktemp("walk")
    sim = simulate("handheld", root / "walk.bag", "ros1", duration_s=3.0, seed=4, columns=180)
    out = root / "odom.tum"
    rc = main(["odom", str(sim.log_path), "-o", str(out), "--gt", "/ground_truth", "--map", str(root / "map.ply"),
               "--plot", str(root / "plots"), "-q"])
    assert rc == 0
    return sim, root


def _in_world(sim, root) -> np.ndarray:
    """The map moved from the odometry's world into the simulated one by the true pose at the first scan."""
    stamps, poses = read_tum(root / "odom.tum")
    gt_stamps, gt_poses = read_tum(sim.gt_path)
    T = interpolate_poses(gt_stamps, gt_poses, stamps[:1])[0] @ inv_pose(poses[0])
    pts = read_point_map(root / "map.ply").astype(np.float64)
    return pts @ T[:3, :3].T + T[:3, 3]


def _plane_p95(pts: np.ndarray, world) -> float:
    """95th percentile of the distance to the floor or ceiling of the points near them, away from every wall, door
    lintel and piece of furniture that reaches that plane (their sides end on it)."""
    xy, m, dists = pts[:, None, :2], WORLD_MARGIN_M, []
    for z in world.plane_z:
        touch = (world.box_lo[:, 2] < z + NEAR_PLANE_M) & (world.box_hi[:, 2] > z - NEAR_PLANE_M)
        lo, hi = world.box_lo[touch, :2] - m, world.box_hi[touch, :2] + m
        in_box = ((xy > lo[None]) & (xy < hi[None])).all(axis=2).any(axis=1)
        cyl = world.cyl[(world.cyl[:, 3] < z + NEAR_PLANE_M) & (world.cyl[:, 4] > z - NEAR_PLANE_M)]
        in_cyl = (np.linalg.norm(xy - cyl[None, :, :2], axis=2) < cyl[None, :, 2] + m).any(axis=1)
        dz = np.abs(pts[:, 2] - z)
        dists.append(dz[(dz < NEAR_PLANE_M) & ~in_box & ~in_cyl])
    near = np.concatenate(dists)
    assert len(near) > 500
    return float(np.percentile(near, 95))


def test_map_holds_one_point_per_voxel_as_metrics_say(run):
    sim, root = run
    pts = read_point_map(root / "map.ply")
    metrics = json.loads((root / "odom.metrics.json").read_text())["map"]
    assert metrics["points"] == len(pts) > 5000 and metrics["voxel_m"] == VOXEL_M
    assert metrics["path"] == str(root / "map.ply") and metrics["scans"] == 30  # every scan of 3 s at 10 Hz
    assert f"element vertex {len(pts)}\n".encode() in (root / "map.ply").read_bytes()[:200]
    keys, inside = voxel_keys(pts.astype(np.float64), VOXEL_M)
    assert inside.all() and len(np.unique(keys)) == len(pts)


def test_map_lies_on_the_simulated_office_in_the_trajectorys_frame(run):
    sim, root = run
    world = build_scenario("handheld", columns=180).world
    pts = _in_world(sim, root)
    lo = np.minimum(world.box_lo.min(axis=0)[:2], (world.cyl[:, :2] - world.cyl[:, 2:3]).min(axis=0))
    hi = np.maximum(world.box_hi.max(axis=0)[:2], (world.cyl[:, :2] + world.cyl[:, 2:3]).max(axis=0))
    assert (pts[:, :2] > lo - WORLD_MARGIN_M).all() and (pts[:, :2] < hi + WORLD_MARGIN_M).all()
    assert (pts[:, 2] > world.plane_z.min() - WORLD_MARGIN_M).all()
    assert (pts[:, 2] < world.plane_z.max() + WORLD_MARGIN_M).all()
    _, gt = read_tum(sim.gt_path)
    reach = np.linalg.norm(pts[:, None, :2] - gt[None, ::50, :2, 3], axis=2).min(axis=1)
    assert reach.max() < 100.0  # the LiDAR's range
    assert _plane_p95(pts, world) < PLANE_P95_M
    start = gt[0, :3, 3]  # a map tilted by a degree about the start, as one left unlevelled would be, fails this
    tilted = (pts - start) @ so3_exp(np.array([np.radians(1.0), 0.0, 0.0])).T + start
    assert _plane_p95(tilted, world) > 2 * PLANE_P95_M


def test_pictures_decode_at_their_size(run):
    _, root = run
    for name in PLOT_FILES:
        w, h = SIZES_IN[name]
        assert mpimg.imread(root / "plots" / name).shape[:2] == (round(h * DPI), round(w * DPI))
    assert mpimg.imread(root / "map.png").shape[:2] == (round(SIZE_IN[1] * DPI), round(SIZE_IN[0] * DPI))


@pytest.mark.parametrize("args, message", [
    (["--map", "{root}/m.txt"], "{root}/m.txt: a map is written as .ply or .pcd; name the file with one of those suffixes"),
    (["--map-voxel", "0.2"], "--map-voxel needs --map FILE (or --viz)"),
    (["--map", "{root}/m.pcd", "--map-voxel", "0"], "--map-voxel must be a positive number of metres, got 0.0"),
    (["--map", "{root}/o.ply", "-o", "{root}/o.ply"],
     "{root}/o.ply: would be both a file of the run (-o {root}/o.ply) and the map (--map); give each output its own path"),
    (["--plot", "{root}/map.ply"], "{root}/map.ply: exists and is not a folder"),
    (["--map", "{root}/map.ply"], "{root}/map.ply: already exists; pass --force to overwrite it"),
    (["--plot", "-"], "--plot writes PNG files into a folder, not standard output: give --plot a path"),
    (["--viz-save", "{root}/v.mcap"], "{root}/v.mcap: a rerun recording is written as .rrd; name the file so"),
])
def test_bad_output_requests_stop_before_the_run(args, message, run, tmp_path, capsys):
    sim, root = run
    out = tmp_path / "x.tum"
    argv = ["odom", str(sim.log_path), "-q", *(a.format(root=root) for a in args)]
    if "-o" not in args:
        argv += ["-o", str(out)]
    assert main(argv) == 2
    assert capsys.readouterr().err.strip() == "lio: error: " + message.format(root=root)
    assert not out.exists() and not (root / "m.pcd").exists()


def test_viz_save_records_each_scan_the_trajectory_and_the_map(run, tmp_path):
    # rerun-sdk is in the test extra: the recording is checked wherever the tests run
    from rerun.chunk import RrdReader

    sim, _ = run
    rrd = tmp_path / "walk.rrd"
    assert main(["odom", str(sim.log_path), "-o", str(tmp_path / "o.tum"), "--viz-save", str(rrd), "-q"]) == 0
    rows, static = {}, {}
    for chunk in RrdReader(rrd).stream():
        rows[chunk.entity_path] = rows.get(chunk.entity_path, 0) + chunk.num_rows
        static[chunk.entity_path] = static.get(chunk.entity_path, False) or chunk.is_static
    assert rows["/world/scan"] == rows["/world/base"] == 30  # one per scan, on the scans' time line
    assert static["/world"] and static["/map"] and static["/world/trajectory"]  # levelling, map, whole path
    assert not list(tmp_path.glob(".walk.rrd*"))  # the temporary recording was renamed into place


def test_viz_without_rerun_says_how_to_install_it(run, tmp_path, capsys, monkeypatch):
    sim, _ = run
    monkeypatch.setitem(__import__("sys").modules, "rerun", None)  # as if not installed
    assert main(["odom", str(sim.log_path), "-o", str(tmp_path / "o.tum"), "--viz"]) == 2
    assert capsys.readouterr().err.strip() == ("lio: error: --viz needs rerun, which is not installed: "
                                               "pip install 'lio-cli[viz]' (or pip install rerun-sdk)")
    assert not (tmp_path / "o.tum").exists()
