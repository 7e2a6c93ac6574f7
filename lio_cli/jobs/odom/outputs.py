"""The files of an odom run: the TUM trajectory with ``NAME.odom.metrics.json`` and ``NAME.odom.config.yaml``
beside it; on request the map (``--map``, with its top view beside it) and the pictures of the trajectory
(``--plot``)."""

from __future__ import annotations

from pathlib import Path

from ...errors import InputError
from ...io.files.trajectory import tum_blocks
from ...model.trajectory import Trajectory
from ..outputs import write_run
from .job import OdomResult

TAG = "odom"  # in the name of every file a run writes
GT_MAX_DIFF_NS = 10_000_000  # pose pairs for the picture's alignment: as the score's



def write_odom(result: OdomResult, out: Path, force: bool) -> list[Path]:
    """The odom run's TUM trajectory, resolved config and metrics; returns the paths written."""
    result.metrics["output"] = str(out)
    return write_run(out, TAG, tum_blocks(result.trajectory.stamps_ns, result.trajectory.poses), result.config,
                     result.metrics, force)


def map_outputs(path: Path) -> list[Path]:
    """The files ``--map PATH`` writes: the cloud and its top view beside it."""
    from ...plots.map import preview_path

    return [Path(path), preview_path(path)]


def write_odom_map(result: OdomResult, path: Path, force: bool) -> list[Path]:
    """The run's map (``OdomJob.map_voxel_m``) as PLY/PCD and its top view with the trajectory over it."""
    from ...io.files.point_clouds import write_point_map
    from ...plots.map import write_map_preview

    cloud, png = map_outputs(path)
    write_point_map(cloud, result.map_points, force)
    voxel = result.metrics["map"]["voxel_m"]
    write_map_preview(result.map_points, png, force, voxel, result.trajectory)
    result.metrics["map"]["path"] = str(cloud)
    return [cloud, png]


def picture_tracks(result: OdomResult, reference: Trajectory | None) -> tuple[list[Trajectory], list[str]]:
    """What ``--plot`` draws: the odometry, or the ground truth with the odometry aligned to it as the score aligns
    (SE(3), from the first pose when the positions lie on a line, unaligned when no stamps pair); notes."""
    odom = Trajectory(result.trajectory.stamps_ns, result.trajectory.poses, "lio odom", "odom")
    if reference is None:
        return [odom], []
    from ..plot import align_to_first  # the evaluation's alignment: loaded only with a reference

    gt = Trajectory(reference.stamps_ns, reference.poses, f"ground truth {reference.name}", reference.kind)
    for mode in ("se3", "origin"):
        try:
            return align_to_first([gt, odom], mode, GT_MAX_DIFF_NS)[0], []
        except InputError as err:
            why = str(err)
    return [gt, odom], [f"--plot: the odometry is drawn unaligned ({why})"]


def write_odom_plots(result: OdomResult, reference: Trajectory | None, folder: Path, force: bool) -> tuple[list[Path], list[str]]:
    """The pictures of ``plots.trajectories`` into ``folder``: (paths, notes)."""
    from ...plots.trajectories import write_trajectory_plots

    tracks, notes = picture_tracks(result, reference)
    paths = write_trajectory_plots(tracks, folder, force)
    result.metrics["plots"] = [str(p) for p in paths]
    return paths, notes


__all__ = ["TAG", "map_outputs", "picture_tracks", "write_odom", "write_odom_map", "write_odom_plots"]
