"""Starting the IMU state from LiDAR-only scans (at the start and after a lost track), and the doubted scan.

A mixin of ``LioOdometry`` (``core/odometry.py``): the window of LiDAR-only scans is aligned with the IMU
(``bootstrap.align``: standing or moving start) and replayed IMU-primed on a fresh map.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ...model.records import ImuBatch, PointCloud
from .bootstrap import align
from ..imu import NavState, propagate
from .pose_checks import lean_on_prior

_MOVING_M = 0.3  # wheels that read exactly zero while the LiDAR window moved this far are no wheels


@dataclass
class WindowScan:
    """A scan registered LiDAR-only while the IMU state is (re)started, kept to be replayed IMU-primed."""

    t_prev_ns: int
    stamp_ns: int
    pose: np.ndarray
    wheel_mps: float
    cloud: PointCloud
    out_index: int


class Restart:
    """The (re)start of the IMU state and the recovery of a doubted scan."""

    def _try_bootstrap(self) -> None:
        """Align the LiDAR-only window with the IMU, then replay its scans IMU-primed on a fresh map."""
        win = self._window
        stamps = np.array([w.stamp_ns for w in win], dtype=np.int64)
        if len(stamps) < 3 or (stamps[-1] - stamps[0]) * 1e-9 < self.cfg.init_window_s:
            return
        imu = ImuBatch.concat(self._imu)
        if len(imu) == 0 or imu.stamps_ns[0] > stamps[0] or imu.stamps_ns[-1] < stamps[-1]:
            self._window = win[1:]  # the IMU does not cover the window yet: slide it
            return
        poses = np.stack([w.pose for w in win])
        wheel = np.array([w.wheel_mps for w in win])
        if np.all(np.nan_to_num(wheel) == 0.0) and np.linalg.norm(poses[-1, :3, 3] - poses[0, :3, 3]) > _MOVING_M:
            wheel = np.full(len(win), np.nan)  # wheels that read exactly zero while the LiDAR moves are no wheels
        bg, ba = self._bias_prior
        ba = np.zeros(3) if ba is None else np.asarray(ba, dtype=np.float64)
        boot = align(stamps, poses, imu, self.ext, gravity_mps2=self.cfg.gravity_mps2, accel_bias=ba, gyro_bias=bg,
                     g_world=self._g_world, wheel_speeds=wheel if np.isfinite(wheel).any() else None,
                     planar=self.planar)
        if self.start is None:
            self.start = boot
        else:
            self._event("recovered", f"IMU state started again: {boot.reason}")
        self._g_world = boot.g_world
        still = boot.static
        n = boot.g_world / np.linalg.norm(boot.g_world)
        if still:  # the IMU means pin gravity and gyro bias; velocity is zero
            P = np.diag([1e-4, 1e-4, 1e-2] + [1e-6] * 3 + [1e-4] * 3 + [1e-6] * 3 + [1e-2] * 3 + [0.0] * 3)
            tilt_mps2 = 0.01
        else:  # the alignment leaves a degree or two of tilt and some velocity to the filter
            P = np.diag([1e-4, 1e-4, 1e-4] + [1e-4] * 3 + [0.04] * 3 + [2.5e-5] * 3 + [1e-2] * 3 + [0.0] * 3)
            tilt_mps2 = 0.4
        if self.planar:
            tilt_mps2 = 0.0
        P[15:18, 15:18] = tilt_mps2**2 * (np.eye(3) - np.outer(n, n)) + 1e-8 * np.eye(3)
        first = win[0]
        # the state at the first scan's start (gyro rotation, constant velocity back over one sweep), so the
        # replay de-skews that scan too
        sweep = propagate(NavState(first.t_prev_ns, np.eye(3), np.zeros(3), np.zeros(3), boot.gyro_bias, ba),
                          imu, first.stamp_ns, self.ext, accel=False)
        R0 = first.pose[:3, :3] @ sweep.state.R.T
        p0 = first.pose[:3, 3] - boot.v_start * (first.stamp_ns - first.t_prev_ns) * 1e-9
        self.state = NavState(first.t_prev_ns, R0, p0, boot.v_start.copy(), boot.gyro_bias.copy(), ba.copy(), P,
                              boot.g_world.copy())
        self._window = []
        # replay the window IMU-primed on a fresh map
        st = self.stats
        used, degenerate = st.used, st.degenerate
        del self.stamps_ns[first.out_index:], self.poses[first.out_index:]
        self._reg, self._dirs_b, self._degeneracy_due = None, [], (0, -1)
        self._last_pose, self._last_ns, self._last_delta, self._last_dt_s = self.state.pose(), None, np.eye(4), 0.0
        for w in win:
            t_prev = w.t_prev_ns if self._last_ns is None else self._last_ns
            if self.imu_mode:
                self._imu_step(w.cloud, t_prev, w.stamp_ns)
            else:  # the replay lost the track again: the rest is the next window
                self._lidar_step(w.cloud, t_prev, w.stamp_ns)
        # the replayed scans were counted once already; they are IMU-primed now unless the replay lost the track
        st.used, st.degenerate = used, degenerate
        self._degeneracy_due = (0, -1)  # its schedule counted the replayed scans
        st.lidar_only_scans -= len(win)

    def _doubted_scan(self, cloud: PointCloud, t_prev: int, t_ref: int, measured: np.ndarray, guess: np.ndarray,
                      frame: np.ndarray, dirs_b: list, reason: str | None):  # -> ScanResult
        """A scan whose registration the IMU state cannot explain: its pose comes from LiDAR-only registration
        (gated around the gyro and the last poses, not around the doubted prediction); the state follows that
        pose and keeps its velocity, biases and gravity. Several such scans in a row drop the state."""
        self.stats.doubted_scans += 1
        kept, g_world, doubt = self.state, self._g_world, self._doubt
        self._lose_imu_state(keep_clock=True)
        res = self._lidar_step(cloud, t_prev, t_ref, retry=True, window=False)
        self.state, self._g_world, self._doubt = kept, g_world, doubt
        if res is None:  # LiDAR-only failed: the prediction-gated registration is all there is
            pose = lean_on_prior(measured, guess, dirs_b)
            res = self._finish(t_ref, pose, frame, None, dirs_b, False)
        elif reason is None:
            # the LiDAR-only pose times the IMU clock as a registered one does: an offset of 20-30 ms makes such
            # scans every few scans, and a window restarted at each was never long enough to find it; the
            # window, marked, may apply a less sharply measured offset (``APPLY_SIGMA_DOUBTED_S``)
            self._track_clock(t_ref, res.pose, doubted=True)
        self.state.R, self.state.p = res.pose[:3, :3].copy(), res.pose[:3, 3].copy()
        if reason is not None:
            self.stats.recoveries += 1
            self._event("recovery", reason + ": back to LiDAR-only scans")
            self._lose_imu_state()
        return res
