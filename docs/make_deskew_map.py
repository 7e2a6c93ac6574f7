#!/usr/bin/env python3
"""Make docs/deskew_map.png: a `lio deskew --map` of a simulated handheld walk beside the same scans not de-skewed.

Both panels place each scan with lio odom's pose of its last point (the instant lio deskew stamps it with);
the left one takes the raw points as they are, the right one is the map `lio deskew` writes. For display both
are moved from the odometry's world (the first scan's, levelled) into the simulated office's by the true pose
at the first scan. Top view of the points between 0.3 m and 2.4 m high (walls, furniture; no floor or ceiling).

    PYTHONPATH=. python docs/make_deskew_map.py            # about a minute
"""

from __future__ import annotations

import sys
import tempfile
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402

from lio_cli.config.deskew import DeskewConfig  # noqa: E402
from lio_cli.core.deskew.sweep_motion import PoseSpline  # noqa: E402
from lio_cli.core.deskew.voxel_map import VoxelMap  # noqa: E402
from lio_cli.io.files.point_clouds import read_point_map  # noqa: E402
from lio_cli.io.messages.pointcloud import decode_pointcloud2  # noqa: E402
from lio_cli.io.logs.reader import open_log  # noqa: E402
from lio_cli.jobs.deskew.job import DeskewJob, run_deskew  # noqa: E402
from lio_cli.geometry import inv_pose  # noqa: E402
from lio_cli.jobs.odom.job import OdomJob, run_odom  # noqa: E402
from lio_cli.simulation.deskew_truth import TrueMotion  # noqa: E402
from lio_cli.simulation.run import simulate  # noqa: E402

VOXEL_M = 0.05
BAND_M = (0.3, 2.4)


def main() -> int:
    out_png = Path(__file__).with_name("deskew_map.png")
    work = Path(tempfile.mkdtemp(prefix="lio-deskew-map-"))
    sim = simulate("handheld", work / "walk.bag", "ros1", duration_s=40.0, seed=0)
    ply = work / "map.ply"
    cfg = DeskewConfig(map_voxel_m=VOXEL_M)
    res = run_deskew(DeskewJob(sim.log_path, work / "walk_deskewed.bag", cfg, ply))
    truth = TrueMotion(sim.truth_path)
    T_bl = truth.T_base_lidar
    traj = run_odom(OdomJob(sim.log_path, cfg.odom_config("imu"))).trajectory
    office = truth.poses(traj.stamps_ns[:1])[0] @ inv_pose(traj.poses[0])  # odometry world -> the office
    poses = PoseSpline(traj.stamps_ns, traj.poses)
    raw = VoxelMap(VOXEL_M)
    with open_log(sim.log_path) as r:
        for _, _, _, msg in r.messages(["/points"], fast=True):
            c = decode_pointcloud2(msg)
            T = poses.at(np.array([c.end_ns]))[0] @ T_bl
            raw.add(c.points @ T[:3, :3].T + T[:3, 3])
    panels = [("raw scans, each placed at its last point's pose", raw.points()),
              (f"lio deskew --map ({res.metrics['motion']['source']} motion)", read_point_map(ply))]
    panels = [(title, pts @ office[:3, :3].T + office[:3, 3]) for title, pts in panels]
    fig, axes = plt.subplots(1, 2, figsize=(9.0, 2.9), dpi=110, sharex=True, sharey=True)
    for ax, (title, pts) in zip(axes, panels):
        keep = (pts[:, 2] > BAND_M[0]) & (pts[:, 2] < BAND_M[1])
        ax.scatter(pts[keep, 0], pts[keep, 1], s=0.05, c="black", linewidths=0, rasterized=True)
        ax.set_title(title, fontsize=9)
        ax.set_aspect("equal")
        ax.set_xlabel("x m", fontsize=8)
        ax.tick_params(labelsize=7)
    axes[0].set_ylabel("y m", fontsize=8)
    axes[0].set_xlim(-0.5, 36.5)
    axes[0].set_ylim(-0.5, 16.5)
    fig.suptitle("simulated handheld walk, 40 s, 16-beam LiDAR: top view of the map, 0.3-2.4 m high", fontsize=9)
    fig.tight_layout()
    fig.savefig(out_png, dpi=110)
    print(f"wrote {out_png} ({out_png.stat().st_size // 1024} kB)", file=sys.stderr)
    return 0


if __name__ == "__main__":
    sys.exit(main())
