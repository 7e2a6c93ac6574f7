"""The (re)start of the IMU state: the window of LiDAR-only scans (at the start, after a lost track) is aligned
with the IMU (``bootstrap.align``: standing or moving start), and its scans replayed IMU-primed on a fresh map."""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import replace

import numpy as np

from ...model.calibration import Extrinsics
from ...model.records import ImuBatch, PointCloud
from ..imu import NavState, propagate
from .bootstrap import Bootstrap, align, imu_still, lidar_still
from .state import OdomState, WindowScan
from .tuning import MAX_START_SLIDE_S, MOVING_M, START_MISFIT_M


def start_state(boot: Bootstrap, first: WindowScan, imu: ImuBatch, ext: Extrinsics, ba: np.ndarray,
                planar: bool) -> NavState:
    """The IMU state at the window's first scan's start (gyro rotation, constant velocity back over one sweep, so
    the replay de-skews that scan too), with the covariance the alignment leaves."""
    n = boot.g_world / np.linalg.norm(boot.g_world)
    if boot.static:  # the IMU means pin gravity and gyro bias; velocity is zero
        P = np.diag([1e-4, 1e-4, 1e-2] + [1e-6] * 3 + [1e-4] * 3 + [1e-6] * 3 + [1e-2] * 3 + [0.0] * 3)
        tilt_mps2 = 0.01
    else:  # the alignment leaves a degree or two of tilt and some velocity to the filter
        P = np.diag([1e-4, 1e-4, 1e-4] + [1e-4] * 3 + [0.04] * 3 + [2.5e-5] * 3 + [1e-2] * 3 + [0.0] * 3)
        tilt_mps2 = 0.4
    if planar:
        tilt_mps2 = 0.0
    P[15:18, 15:18] = tilt_mps2**2 * (np.eye(3) - np.outer(n, n)) + 1e-8 * np.eye(3)
    sweep = propagate(NavState(first.t_prev_ns, np.eye(3), np.zeros(3), np.zeros(3), boot.gyro_bias, ba),
                      imu, first.stamp_ns, ext, accel=False)
    R0 = first.pose[:3, :3] @ sweep.state.R.T
    p0 = first.pose[:3, 3] - boot.v_start * (first.stamp_ns - first.t_prev_ns) * 1e-9
    return NavState(first.t_prev_ns, R0, p0, boot.v_start.copy(), boot.gyro_bias.copy(), ba.copy(), P,
                    boot.g_world.copy())


def velocity_before(boot: Bootstrap, first: WindowScan, later: WindowScan, imu: ImuBatch, ext: Extrinsics,
                    ba: np.ndarray) -> np.ndarray:
    """The world velocity at ``first``'s stamp from the aligned velocity at ``later``'s (the window's first scan):
    gravity and the specific force integrated back from ``first``'s LiDAR-only orientation."""
    s0 = NavState(first.stamp_ns, first.pose[:3, :3].copy(), np.zeros(3), np.zeros(3), boot.gyro_bias, ba)
    beta = propagate(s0, imu, later.stamp_ns, ext, g_world=np.zeros(3)).state.v
    return boot.v_start - boot.g_world * (later.stamp_ns - first.stamp_ns) * 1e-9 - beta


def try_start(o: OdomState) -> list[WindowScan] | None:
    """Start the IMU state from the window if it spans ``init_window_s`` and the IMU covers it (else slide it);
    return the window's scans to replay, or None."""
    win = o.startup.scans
    stamps = np.array([w.stamp_ns for w in win], dtype=np.int64)
    if len(stamps) < 3 or (stamps[-1] - stamps[0]) * 1e-9 < o.cfg.init_window_s:
        return None
    imu = ImuBatch.concat(o.imu.batches)
    if len(imu) == 0 or imu.stamps_ns[0] > stamps[0] or imu.stamps_ns[-1] < stamps[-1]:
        o.startup.scans = win[1:]  # the IMU does not cover the window yet: slide it
        return None
    poses = np.stack([w.pose for w in win])
    wheel = np.array([w.wheel_mps for w in win])
    if np.all(np.nan_to_num(wheel) == 0.0) and np.linalg.norm(poses[-1, :3, 3] - poses[0, :3, 3]) > MOVING_M:
        wheel = np.full(len(win), np.nan)  # wheels that read exactly zero while the LiDAR moves are no wheels
    bg, ba = o.settings.bias_prior
    ba = np.zeros(3) if ba is None else np.asarray(ba, dtype=np.float64)
    boot = align(stamps, poses, imu, o.ext, gravity_mps2=o.cfg.gravity_mps2, accel_bias=ba, gyro_bias=bg,
                 g_world=o.nav.g_world, wheel_speeds=wheel if np.isfinite(wheel).any() else None,
                 planar=o.settings.planar)
    held = o.startup.held
    if o.startup.bootstrap is None and not boot.static and not np.isfinite(wheel).any() and \
            boot.residual_m > START_MISFIT_M and (stamps[0] - (held or win)[0].stamp_ns) * 1e-9 < MAX_START_SLIDE_S:
        # LiDAR-only registrations stuck near their standstill guess while the car moves (the IMU felt no
        # such stop): the window slides until its poses fit the IMU; the scans it leaves are replayed too
        held.append(win[0])
        o.startup.scans = win[1:]
        return None
    if held and o.startup.bootstrap is None:
        boot = replace(boot, v_start=velocity_before(boot, held[0], win[0], imu, o.ext, ba))
        win = held + win
        o.startup.held = []
    if o.startup.bootstrap is None:
        o.startup.bootstrap = boot
    else:
        o.event("recovered", f"IMU state started again: {boot.reason}")
    o.nav.g_world = boot.g_world
    o.nav.state = start_state(boot, win[0], imu, o.ext, ba, o.settings.planar)
    o.startup.scans = []
    return win


def specific_force_levels(o: OdomState) -> bool:
    """When the IMU state never started (a log shorter than the start-up window): whether the mean specific
    force around the first scans may stand for gravity. Only when the LiDAR (over the window's scans) and the IMU
    agree the platform stood still: moving, the force holds the acceleration too (a car driving off at 4 m/s^2
    reads as a 22 deg tilt), and the IMU alone cannot tell the two apart."""
    win = o.startup.scans
    imu = ImuBatch.concat(o.imu.batches)
    if not win or len(imu) < 3:
        return False
    sel = (imu.stamps_ns >= win[0].t_prev_ns) & (imu.stamps_ns <= win[-1].stamp_ns)
    imu = ImuBatch(imu.frame_id, imu.stamps_ns[sel], imu.gyro_radps[sel], imu.accel_mps2[sel])
    ba = o.settings.bias_prior[1]
    ba = np.zeros(3) if ba is None else np.asarray(ba, dtype=np.float64)
    poses = np.stack([w.pose for w in win])
    return lidar_still(poses) and imu_still(imu, o.cfg.gravity_mps2, ba)


def replay(o: OdomState, win: list[WindowScan], step: Callable[[PointCloud, int, int], object]) -> None:
    """Register the window's scans again through ``step`` (IMU-primed, unless the replay loses the track) on a
    fresh map, in place of their LiDAR-only poses."""
    st = o.stats
    used, degenerate = st.used, st.degenerate
    o.track.restart_at(win[0].out_index, o.nav.state.pose())
    o.reg, o.degeneracy.dirs_b, o.degeneracy.due = None, [], (0, -1)
    for w in win:
        t_prev = w.t_prev_ns if o.track.last_ns is None else o.track.last_ns
        step(w.cloud, t_prev, w.stamp_ns)
    # the replayed scans were counted once already; they are IMU-primed now unless the replay lost the track
    st.used, st.degenerate = used, degenerate
    o.degeneracy.reset()  # its schedule counted the replayed scans
    st.lidar_only_scans -= len(win)
