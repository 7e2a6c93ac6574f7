"""The odometry's LiDAR-only step (a mixin of ``LioOdometry``): the start-up window, recoveries, runs without
an IMU, and how a lost track ends a run."""

from __future__ import annotations

import time
from dataclasses import dataclass

import numpy as np

from ...errors import ProcessingError
from ...geometry import inv_pose, project_to_se2
from ...model.records import ImuBatch, PointCloud
from .restart import WindowScan
from .pose_checks import exceeds_jump, lean_on_prior, untouched

_MAP_RESTART_SCANS = 3  # a one-scan map that this many scans in a row cannot match is dropped...
_MAX_MAP_RESTARTS = 3  # ...at most this often per run
_GYRO_PRIOR_GATE_M = 1.0  # LiDAR-only scans with the gyro's rotation: the translation guess is constant velocity
_GYRO_PRIOR_JUMP_M = 2.0  # ...so a registration this far from it (or turned this much) has failed
_GYRO_PRIOR_JUMP_RAD = np.radians(10.0)


class Diverged(ProcessingError):
    """The track is lost for good: LiDAR-only registration failed for ``max_lost_scans`` scans in a row."""


@dataclass
class ScanResult:
    stamp_ns: int  # the reference instant the scan was de-skewed to
    pose: np.ndarray  # T_world_base after correction (internal world frame)
    degenerate: bool
    failed: bool


class LidarSteps:
    """Registration without the IMU state (gyro-primed where the IMU is mounted)."""

    def _lidar_step(self, cloud: PointCloud, t_prev: int, t_ref: int, retry: bool = False,
                    window: bool = True, mapped: bool = True) -> ScanResult | None:
        """Register one scan LiDAR-only. ``retry``: a scan the IMU prediction could not explain; return None
        (and change nothing) if it fails here too, since then the scan is bad, not the IMU state. ``window``:
        the scan may start the IMU state. ``mapped``: the scan joins the map (unless it failed)."""
        st = self.stats
        tick = time.perf_counter()
        imu_gap = self._imu_hole(t_prev, t_ref)  # held rates would prime it wrongly: constant velocity instead
        guess, knots, knot_poses, gyro_primed = self._lidar_prior(t_prev, t_ref, imu_gap)
        st.times_s["propagate"] += time.perf_counter() - tick
        if imu_gap and self._reg is not None and not self._reg.empty:  # no rotation prior: hypotheses
            tick = time.perf_counter()
            blind = self._register_blind(cloud, t_prev, t_ref, guess)
            if blind is None:
                return None
            points, frame, measured = blind
        else:
            points = self._prepare(cloud, knots, knot_poses, t_ref)
            if points is None:
                return None
            tick = time.perf_counter()
            frame, source = self._reg.downsample(points)
            measured = self._reg.register(source, guess, adaptive=True, gate_m=_GYRO_PRIOR_GATE_M if gyro_primed else None)
        st.times_s["register"] += time.perf_counter() - tick
        if self.planar:
            measured = project_to_se2(measured)
        failed = not self._reg.empty and (not np.isfinite(measured).all()
                                          or untouched(measured, guess)
                                          or (gyro_primed and exceeds_jump(measured, guess, _GYRO_PRIOR_JUMP_M, _GYRO_PRIOR_JUMP_RAD)))
        if failed and retry:
            return None
        dirs_b = self._degeneracy(points, guess[:3, :3])
        pose = guess if failed else lean_on_prior(measured, guess, dirs_b)
        if self.planar:
            pose = project_to_se2(pose)
        st.lidar_only_scans += 1
        if failed:
            st.registration_failures += 1
            self._count_lost(t_ref)
            if self._reg.scans == 1 and self._lost >= _MAP_RESTART_SCANS and self._map_restarts < _MAX_MAP_RESTARTS:
                # the map's only scan matched none of the scans after it: that scan is the bad one (damaged, or
                # another world), so the map starts again from the next scan, the pose carried by the prior
                self._reg, self._map_restarts, self._window = None, self._map_restarts + 1, []
                self._degeneracy_due = (0, -1)  # a new scene: analysed at once
                self._event("map restarted", f"the map's first scan matched none of the {self._lost} after it")
        else:
            self._lost = 0
        keep = mapped and not failed
        result = self._finish(t_ref, pose, frame if keep else None, inv_pose(guess) @ measured if keep else None,
                              dirs_b, failed)
        if imu_gap:
            self._window = []  # the IMU state starts from scans after the gap
        elif self.use_imu and self.imu_mounted and self._imu and not failed and window and not self.gyro_only:
            if self._first_f_base is None:
                imu = ImuBatch.concat(self._imu)
                ba = np.zeros(3) if self._bias_prior[1] is None else np.asarray(self._bias_prior[1], dtype=np.float64)
                self._first_f_base = self.ext.R_base_imu @ (imu.accel_mps2.mean(axis=0) - ba)
            self._window.append(WindowScan(t_prev, t_ref, pose, self._wheel_speed(t_ref), cloud, len(self.poses) - 1))
            self._try_bootstrap()
        return result

    def _count_lost(self, t_ref: int) -> None:
        """One more scan in a row that no registration could place; too many end the run."""
        self._lost += 1
        if self._lost >= self.cfg.max_lost_scans:
            raise Diverged(f"lost track at scan {self.stats.scans} (stamp {t_ref * 1e-9:.3f} s): no registration, "
                           f"IMU-primed or LiDAR-only, could place {self._lost} scans in a row")
