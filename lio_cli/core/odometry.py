"""IMU-primed scan matching: the lecture's LIO pipeline on kiss-icp's registration and voxel map.

Per scan: propagate the IMU state to the scan's reference instant (its end by default), de-skew every
point with the propagated pose at its own stamp, register the de-skewed scan to the local map starting
from the IMU prediction, check the geometry for degenerate directions, then correct the state (EKF or
complementary filter) so the corrected velocity and biases prime the next scan.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field

import numpy as np

from ..config.odom import OdomConfig
from ..geometry import inv_pose, project_to_se2
from ..model.calibration import Extrinsics
from ..model.records import ImuBatch, OdometryRecord, PointCloud
from .degeneracy import degenerate_directions
from .filter import (complementary_update, complementary_velocity_update, ekf_body_velocity_update, ekf_pose_update,
                     position_noise)
from .imu import NavState, flatten_planar, propagate
from .motion_compensation import constant_velocity_knots, deskew, to_base
from .registration import ScanRegistration, auto_voxel_size
from .startup import StartUp, start_up
from .wheel import mean_twist, planar_delta

_MAX_JUMP_M = 1.0  # a registration this far from the IMU prediction within one scan is treated as failed
_MAX_JUMP_RAD = 0.35
_WHEEL_KEEP_NS = 1_000_000_000  # wheel records older than this behind the last scan are dropped
_IMU_PRIOR_CORRESPONDENCE_M = 0.5


@dataclass
class ScanResult:
    stamp_ns: int  # the reference instant the scan was de-skewed to
    pose: np.ndarray  # T_world_base after correction
    degenerate: bool
    failed: bool


@dataclass
class OdomStats:
    scans: int = 0
    used: int = 0
    skipped_few_points: int = 0
    skipped_out_of_order: int = 0
    registration_failures: int = 0
    degenerate: int = 0
    imu_gaps: int = 0
    wheel_updates: int = 0
    times_s: dict[str, float] = field(default_factory=lambda: {"propagate": 0.0, "deskew": 0.0, "register": 0.0,
                                                               "degeneracy": 0.0, "fuse": 0.0})

    def counts(self) -> dict[str, int]:
        """Every counter (not the times), for metrics."""
        counts = {k: v for k, v in vars(self).items() if k not in ("scans", "times_s")}
        return {"total": self.scans, **counts}


class LioOdometry:
    """Feed IMU batches, wheel records and scans (in time order); get one pose per scan."""

    def __init__(self, cfg: OdomConfig, ext: Extrinsics, *, use_imu: bool, planar: bool,
                 gyro_bias: np.ndarray | None = None, accel_bias: np.ndarray | None = None) -> None:
        self.cfg = cfg
        self.ext = ext
        self.use_imu = use_imu
        self.planar = planar
        self.stats = OdomStats()
        self.start: StartUp | None = None
        self.state: NavState | None = None
        self._imu: list[ImuBatch] = []
        self._wheel: list[OdometryRecord] = []
        self._reg: ScanRegistration | None = None
        self._last_pose = np.eye(4)
        self._last_delta = np.eye(4)
        self._last_ns: int | None = None
        self._imu_prior = use_imu and cfg.prior == "imu"
        self._deskew = cfg.resolved_deskew()
        self._bias_prior = (gyro_bias, accel_bias)  # from a calibration file, if any
        self._dirs_b: list[np.ndarray] = []  # degenerate directions of the last analysed scan (its base frame)

    @property
    def voxel_size_m(self) -> float | None:
        """The map's voxel size, once the first scan has set it."""
        return self._reg.voxel_size_m if self._reg is not None else None

    # ---- inputs -------------------------------------------------------------------------------
    def add_imu(self, batch: ImuBatch) -> None:
        self._imu.append(batch)

    def add_wheel(self, rec: OdometryRecord) -> None:
        self._wheel.append(rec)

    def imu_from_ns(self) -> int:
        return int(self._imu[0].stamps_ns[0]) if self._imu else 0

    def imu_until_ns(self) -> int | None:
        return int(self._imu[-1].stamps_ns[-1]) if self._imu else None

    def _imu_window(self, t0_ns: int) -> ImuBatch:
        """IMU samples from just before ``t0_ns`` on; older batches are dropped (bounded memory)."""
        imu = ImuBatch.concat(self._imu)
        if len(imu):
            keep = max(0, int(np.searchsorted(imu.stamps_ns, t0_ns)) - 2)
            imu = ImuBatch(imu.frame_id, imu.stamps_ns[keep:], imu.gyro_radps[keep:], imu.accel_mps2[keep:])
        self._imu = [imu] if len(imu) else []
        return imu

    # ---- start-up -----------------------------------------------------------------------------
    def _initialise(self, t0_ns: int, start: StartUp) -> None:
        self.start = start
        P = np.diag([1e-4, 1e-4, 1e-2] + [1e-6] * 3 + ([1e-4] * 3 if start.static else [1.0] * 3)
                    + ([1e-6] * 3 if start.static else [1e-4] * 3) + [1e-2] * 3)
        bg, ba = self._bias_prior
        self.state = NavState(t0_ns, start.R_world_base.copy(), np.zeros(3), np.zeros(3),
                              np.asarray(bg, dtype=np.float64) if bg is not None else start.gyro_bias.copy(),
                              np.asarray(ba, dtype=np.float64) if ba is not None else np.zeros(3), P)
        self._last_pose = self.state.pose()

    # ---- one scan -----------------------------------------------------------------------------
    def process(self, cloud: PointCloud) -> ScanResult | None:
        cfg, st = self.cfg, self.stats
        st.scans += 1
        if len(cloud.points) < cfg.registration.min_points:
            st.skipped_few_points += 1
            return None
        t_ref = cloud.end_ns if cfg.scan_reference == "end" else cloud.start_ns
        if self._last_ns is not None and t_ref <= self._last_ns:
            st.skipped_out_of_order += 1  # a scan ending before the previous one cannot be placed
            return None
        if self.state is None:
            imu = ImuBatch.concat(self._imu)
            R_bi = self.ext.R_base_imu
            window = int(cfg.static_init_s * 1e9)
            start = start_up(imu, R_bi, window, cfg.gravity_mps2, accel_bias=self._bias_prior[1]) if self.use_imu else \
                StartUp(False, np.eye(3), np.zeros(3), 0, "no IMU in use: level start at the origin")
            self._initialise(cloud.start_ns, start)
        t_prev = self.state.stamp_ns if self._last_ns is None else self._last_ns

        # 1. predict the motion over [t_prev, t_ref]
        tick = time.perf_counter()
        prop = None
        if self.use_imu:
            imu = self._imu_window(t_prev)
            prop = propagate(self.state, imu, t_ref, self.ext, gravity_mps2=cfg.gravity_mps2,
                             noise=cfg.fusion.imu if cfg.fusion.method == "ekf" else None, planar=self.planar)
            st.imu_gaps += int(prop.gap)
            self.state = prop.state
            self._wheel_update(t_prev, t_ref)
        st.times_s["propagate"] += time.perf_counter() - tick

        # 2. de-skew
        tick = time.perf_counter()
        dt_scan = (t_ref - t_prev) * 1e-9
        cv_delta = self._last_delta  # constant velocity: the last inter-scan motion again
        mode = self._deskew
        if mode == "imu" and prop is not None:
            points = deskew(cloud.points, cloud.point_stamps_ns, prop.stamps_ns, prop.poses, t_ref, self.ext.T_base_lidar)
        elif mode in ("constant-velocity", "imu"):
            knots, poses = constant_velocity_knots(cv_delta, t_prev, t_ref)
            points = deskew(cloud.points, cloud.point_stamps_ns, knots, poses, t_ref, self.ext.T_base_lidar)
        else:
            points = to_base(cloud.points, self.ext.T_base_lidar)
        rng = np.linalg.norm(points, axis=1)
        points = points[(rng >= cfg.registration.min_range_m) & (rng <= cfg.registration.max_range_m)]
        if len(points) < cfg.registration.min_points:
            st.skipped_few_points += 1
            return None
        st.times_s["deskew"] += time.perf_counter() - tick

        # 3. register, seeded with the prediction
        tick = time.perf_counter()
        if self._reg is None:
            fixed = cfg.registration.max_correspondence_m
            if fixed is None and self._imu_prior:
                fixed = _IMU_PRIOR_CORRESPONDENCE_M
            self._reg = ScanRegistration(cfg.registration, cfg.registration.voxel_size_m or auto_voxel_size(rng),
                                         imu_prior=self._imu_prior, planar=self.planar, fixed_correspondence_m=fixed)
        guess = self._guess(cv_delta, t_prev, t_ref)
        frame, source = self._reg.downsample(points)
        measured = self._reg.register(source, guess)
        st.times_s["register"] += time.perf_counter() - tick

        tick = time.perf_counter()
        if self._reg.empty:
            dirs_b = []
        elif st.used % cfg.fusion.degeneracy_every == 0:  # geometry changes little from one scan to the next
            dirs_b = self._dirs_b = degenerate_directions(points, self.planar, cfg.fusion.degeneracy_ratio)
        else:
            dirs_b = [self.state.R.T @ self._last_pose[:3, :3] @ d for d in self._dirs_b] if self.use_imu else self._dirs_b
        st.times_s["degeneracy"] += time.perf_counter() - tick
        if self.planar:
            measured = project_to_se2(measured)
        failed = self._registration_failed(measured, guess)
        if failed:
            st.registration_failures += 1
            measured = guess
        st.degenerate += int(bool(dirs_b))

        # 4. correct the state
        tick = time.perf_counter()
        pose = self._correct(measured, guess, dirs_b, dt_scan, failed)
        st.times_s["fuse"] += time.perf_counter() - tick

        self._reg.accept(None if failed else inv_pose(guess) @ measured, frame, pose)
        self._last_delta = inv_pose(self._last_pose) @ pose
        self._last_pose = pose
        self._last_ns = t_ref
        self._wheel = [w for w in self._wheel if w.stamp_ns > t_ref - _WHEEL_KEEP_NS]  # bounded memory
        st.used += 1
        return ScanResult(t_ref, pose, bool(dirs_b), failed)

    def _registration_failed(self, measured: np.ndarray, guess: np.ndarray) -> bool:
        """Non-finite, untouched (no correspondence at all), or implausibly far from the IMU prediction."""
        if not np.isfinite(measured).all():
            return True
        if self._reg.empty:
            return False
        if np.allclose(measured, guess, rtol=0.0, atol=1e-12):  # ICP returns the guess itself when nothing matched
            return True
        if not self.use_imu:
            return False
        jump = inv_pose(guess) @ measured
        angle = np.arccos(np.clip((np.trace(jump[:3, :3]) - 1.0) / 2.0, -1.0, 1.0))
        return bool(np.linalg.norm(jump[:3, 3]) > _MAX_JUMP_M or angle > _MAX_JUMP_RAD)

    def _guess(self, cv_delta: np.ndarray, t_prev: int, t_ref: int) -> np.ndarray:
        prior = self.cfg.prior
        if prior == "imu" and self.use_imu:
            return self.state.pose()
        if prior == "constant-velocity":
            return self._last_pose @ cv_delta
        if prior == "wheel":
            return self._last_pose @ self._wheel_delta(t_prev, t_ref)
        return self._last_pose.copy()

    def _wheel_delta(self, t0: int, t1: int) -> np.ndarray:
        """Planar motion integrated from wheel speed and yaw rate over [t0, t1] (lecture's kinematics)."""
        twist = mean_twist(self._wheel, t0 - 100_000_000, t1)
        if twist is None:
            return self._last_delta
        return planar_delta(twist[0], twist[1], (t1 - t0) * 1e-9)

    def _wheel_update(self, t0: int, t1: int) -> None:
        """Wheel speed over the scan (forward, no side slip) corrects the predicted velocity."""
        if not self.cfg.use_wheel or not self._wheel:
            return
        twist = mean_twist(self._wheel, t0, t1 + 20_000_000)
        if twist is None:
            return
        v_body = np.array([twist[0], 0.0, 0.0])
        fc = self.cfg.fusion
        if fc.method == "ekf":
            s = fc.wheel_speed_sigma_mps
            ekf_body_velocity_update(self.state, v_body, np.array([s, 2 * s, 2 * s]))
        else:
            complementary_velocity_update(self.state, v_body, fc.wheel_beta)
        self.stats.wheel_updates += 1

    def _correct(self, measured: np.ndarray, guess: np.ndarray, dirs_b: list[np.ndarray], dt_s: float,
                 failed: bool) -> np.ndarray:
        fc = self.cfg.fusion
        if not self.use_imu:
            pose = measured.copy()
            if dirs_b and not failed:  # lean on the prior along unconstrained directions
                R = guess[:3, :3]
                dp = measured[:3, 3] - guess[:3, 3]
                for d in dirs_b:
                    dw = R @ d
                    dp = dp - dw * (dw @ dp)
                pose[:3, 3] = guess[:3, 3] + dp
            return project_to_se2(pose) if self.planar else pose
        if failed:
            return self.state.pose()
        dirs_w = [self.state.R @ d for d in dirs_b]
        if fc.method == "ekf":
            cov = position_noise(fc.position_sigma_m, dirs_w, fc.degenerate_sigma_m)
            ekf_pose_update(self.state, measured, fc.rotation_sigma_rad, cov)
        else:
            complementary_update(self.state, measured, fc.alpha, dt_s, self.ext.R_base_imu, dirs_w)
        if self.planar:
            flatten_planar(self.state)
        return self.state.pose()


__all__ = ["LioOdometry", "ScanResult", "OdomStats"]
