"""What every scan step shares: the de-skewed points in range (and the map they start), the degeneracy check on
its schedule, and the scan's pose recorded on the track."""

from __future__ import annotations

import time

import numpy as np

from ...buffers import ArrayPool
from ...config.odom import FusionConfig, RegistrationConfig
from ...geometry import row_norms
from ...model.records import PointCloud
from ..motion_compensation import deskew, to_base
from .degeneracy import CLEAR_MARGIN, analyse_degeneracy
from .registration import ScanRegistration, auto_voxel_size
from .state import DegeneracySchedule, OdomState, ScanResult
from .tuning import IMU_PRIOR_CORRESPONDENCE_M, WHEEL_KEEP_NS

_POOL = ArrayPool()  # the points in range of each scan


def points_in_range(cloud: PointCloud, knots_ns, knot_poses, t_ref: int, T_base_lidar: np.ndarray,
                    rc: RegistrationConfig) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(points in the base frame at ``t_ref``, de-skewed by the knots unless None; their ranges; the mask of those
    within the range limits)."""
    if knots_ns is None:
        points = to_base(cloud.points, T_base_lidar)
    else:
        points = deskew(cloud.points, cloud.point_stamps_ns, knots_ns, knot_poses, t_ref, T_base_lidar)
    rng = row_norms(points)
    keep = (rng >= rc.min_range_m) & (rng <= rc.max_range_m)
    return points, rng, keep


def new_map(rc: RegistrationConfig, ranges_m: np.ndarray, *, imu_prior: bool, planar: bool) -> ScanRegistration:
    """The local map, its voxel size from the first scan's ranges unless configured."""
    fixed = rc.max_correspondence_m
    if fixed is None and imu_prior:
        fixed = IMU_PRIOR_CORRESPONDENCE_M
    return ScanRegistration(rc, rc.voxel_size_m or auto_voxel_size(ranges_m), imu_prior=imu_prior, planar=planar,
                            fixed_correspondence_m=fixed)


def prepare(o: OdomState, cloud: PointCloud, knots_ns, knot_poses, t_ref: int) -> np.ndarray | None:
    """De-skewed points in the base frame at ``t_ref`` within the range limits, or None if too few (counted)."""
    rc = o.cfg.registration
    tick = time.process_time()
    points, rng, keep = points_in_range(cloud, knots_ns, knot_poses, t_ref, o.ext.T_base_lidar, rc)
    o.stats.times_s["deskew"] += time.process_time() - tick
    kept = int(np.count_nonzero(keep))
    if kept < rc.min_points:
        o.stats.skipped_few_points += 1
        return None
    if o.reg is None:
        o.reg = new_map(rc, rng[keep], imu_prior=o.settings.imu_prior, planar=o.settings.planar)
    if kept == len(points):  # all in range: no copy
        return points
    # numpy's points[keep] on (N, 3) rows is ~20x slower
    return np.compress(keep, points, axis=0, out=_POOL.empty((kept, 3)))


def scheduled_directions(schedule: DegeneracySchedule, points: np.ndarray, R_now: np.ndarray, last_pose: np.ndarray,
                         used: int, map_empty: bool, planar: bool, fc: FusionConfig) -> list[np.ndarray]:
    """Degenerate directions (base frame) of a scan: analysed on the schedule, else the last analysis' turned
    into this scan's frame. A scan analysed last is analysed again when registered again (a retry)."""
    if map_empty:
        return []
    if used % fc.degeneracy_every == 0 and (used >= schedule.due[0] or used == schedule.due[1]):
        found = analyse_degeneracy(points, planar, fc.degeneracy_ratio)
        schedule.dirs_b = found.directions
        schedule.clear_scene = found.margin >= CLEAR_MARGIN
        every = fc.degeneracy_every_clear if schedule.clear_scene else fc.degeneracy_every
        schedule.due = (used + every, used)
        return found.directions
    return [R_now.T @ last_pose[:3, :3] @ d for d in schedule.dirs_b]


def degeneracy(o: OdomState, points: np.ndarray, R_now: np.ndarray) -> list[np.ndarray]:
    """``scheduled_directions`` of the scan, timed."""
    tick = time.process_time()
    dirs_b = scheduled_directions(o.degeneracy, points, R_now, o.track.last_pose, o.stats.used, o.reg.empty,
                                  o.settings.planar, o.cfg.fusion)
    o.stats.times_s["degeneracy"] += time.process_time() - tick
    return dirs_b


def finish(o: OdomState, t_ref: int, pose: np.ndarray, frame: np.ndarray | None, correction: np.ndarray | None,
           dirs_b: list, failed: bool, points: np.ndarray | None = None) -> ScanResult:
    """Record the scan's pose; ``frame`` (None for a failed scan, which stays out of the map) joins the map, and
    ``points`` (its de-skewed points) go to ``o.scan_sink`` with it."""
    o.track.predicted_ns.discard(t_ref)  # a scan registered again (a replay)
    if frame is not None:
        o.reg.accept(correction, frame, pose)
    o.track.append(t_ref, pose)
    if o.scan_sink is not None:
        o.scan_sink(t_ref, points if frame is not None else None)
    keep_from = o.startup.hold_ns if o.startup.scans else t_ref
    o.wheel = [w for w in o.wheel if w.stamp_ns > keep_from - WHEEL_KEEP_NS]  # bounded memory
    o.stats.degenerate += int(bool(dirs_b))
    o.stats.used += 1
    return ScanResult(t_ref, pose, bool(dirs_b), failed)
