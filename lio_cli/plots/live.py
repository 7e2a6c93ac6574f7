"""``lio odom --viz``: the run seen in rerun (the optional ``viz`` extra, ``rerun-sdk``), live in its viewer or
recorded to an ``.rrd`` file: each scan (voxel-thinned) at its pose as its pose settles, the base's pose, the
trajectory so far, and at the end the map.

Entities: ``world`` is the odometry's internal world (the first scan's base), levelled into the root frame (the
written trajectory's world) by a transform logged at the end; ``world/scan``, ``world/base`` and
``world/trajectory`` live in it; ``map`` is the run's map, already in the root frame. Time: the ``time``
timeline, the scans' stamps.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from ..core.deskew.voxel_map import voxel_keys
from ..errors import ConfigError
from ..io.files.atomic import remove_path, replace_path, temp_sibling

SCAN_VOXEL_M = 0.2  # a scan is drawn thinned to one point per voxel this size
TRAJECTORY_EVERY = 20  # scans between redraws of the whole trajectory so far
INSTALL = "pip install 'lio-cli[viz]' (or pip install rerun-sdk)"


def rerun_module():
    """The rerun module, or a ConfigError saying how to install it."""
    try:
        import rerun
    except ImportError as err:
        raise ConfigError(f"--viz needs rerun, which is not installed: {INSTALL}") from err
    return rerun


def thin(points: np.ndarray, voxel_m: float) -> np.ndarray:
    """The first point of each occupied voxel."""
    if len(points) == 0:
        return points
    keys, _ = voxel_keys(np.asarray(points, dtype=np.float64), voxel_m)
    _, first = np.unique(keys, return_index=True)
    return points[np.sort(first)]


class LiveView:
    """Log a run to rerun: ``scan`` per settled scan (the map's ``on_settled``), ``finish`` at the end, ``close``
    always (a recording is renamed into place only when finished)."""

    def __init__(self, save: Path | None, spawn: bool, name: str) -> None:
        rr = rerun_module()
        self.rr, self.save, self.positions, self.scans = rr, save, [], 0
        self.rec = rr.RecordingStream("lio", recording_id=name)
        self.tmp = temp_sibling(save) if save is not None else None
        if self.tmp is not None:
            self.rec.save(str(self.tmp))
        if spawn:
            self.rec.spawn()
        self.rec.log("/", rr.ViewCoordinates.RIGHT_HAND_Z_UP, static=True)
        self.done = False

    def scan(self, stamp_ns: int, T_world_base: np.ndarray, points_base: np.ndarray) -> None:
        rr, rec = self.rr, self.rec
        rec.set_time("time", timestamp=np.datetime64(int(stamp_ns), "ns"))
        pts = thin(points_base, SCAN_VOXEL_M).astype(np.float64)
        R, t = T_world_base[:3, :3], T_world_base[:3, 3]
        rec.log("world/scan", rr.Points3D(pts @ R.T + t, radii=0.03, colors=[90, 160, 255]))
        rec.log("world/base", rr.Transform3D(translation=t, mat3x3=R))
        self.positions.append(t.copy())
        self.scans += 1
        if self.scans % TRAJECTORY_EVERY == 1:
            rec.log("world/trajectory", rr.LineStrips3D([np.array(self.positions)], colors=[230, 60, 50]))

    def finish(self, level: np.ndarray, map_points: np.ndarray | None) -> None:
        """The levelling of the internal world, the whole trajectory and the map; then the recording is complete."""
        rr, rec = self.rr, self.rec
        rec.log("world", rr.Transform3D(translation=level[:3, 3], mat3x3=level[:3, :3]), static=True)
        if self.positions:
            rec.log("world/trajectory", rr.LineStrips3D([np.array(self.positions)], colors=[230, 60, 50]), static=True)
        if map_points is not None:
            rec.log("map", rr.Points3D(map_points, radii=0.02, colors=[200, 200, 200]), static=True)
        self.done = True

    def close(self) -> Path | None:
        """Flush; a finished recording replaces ``save``, an unfinished one is removed. The recording's path, if any."""
        self.rec.flush()
        self.rec.disconnect()
        if self.tmp is None:
            return None
        if not self.done:
            remove_path(self.tmp)
            return None
        replace_path(self.tmp, self.save)
        return self.save


__all__ = ["INSTALL", "LiveView", "SCAN_VOXEL_M", "rerun_module", "thin"]
