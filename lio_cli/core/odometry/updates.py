"""The odometry's state updates and plausibility checks: priors, wheel speed, EKF/complementary corrections,
the innovation and state guards that send it back to LiDAR-only scans, and the online IMU clock tracking.

A mixin of ``LioOdometry`` (``core/odometry.py``), split out to keep each module readable; it uses the
odometry's attributes (``cfg``, ``state``, ``stats``, ``ext``, ``planar``, ``_wheel``, ``_reg`` ...).
"""

from __future__ import annotations

import numpy as np

from ...geometry import inv_pose
from ...model.records import ImuBatch
from .filter import (complementary_update, complementary_velocity_update, ekf_body_velocity_update, ekf_pose_update,
                     pose_innovation_nis, position_noise)
from ..imu import NavState, flatten_planar, propagate
from ..motion_compensation import constant_velocity_knots
from .pose_checks import exceeds_jump, scale_delta, untouched
from .wheel import mean_twist, planar_delta

_MAX_JUMP_M = 1.0  # a registration this far from the IMU prediction within one scan is treated as failed
_MAX_JUMP_RAD = 0.35
_NIS_LIMIT = 100.0  # a pose innovation this far outside its covariance (chi-square 6 dof: 22 at 99.9 %; a 15 ms IMU
# clock offset on fast yaw sweeps reaches 80)...
_NIS_SCANS = 3  # ...this many scans in a row means the IMU state no longer explains the scans
_MOVING_MPS = 0.3  # faster than this, an exactly-zero wheel twist is not a wheel at rest
_MAX_BIAS_GYRO_RADPS = 0.5
_PREDICT_MIN_MAP_SCANS = 20  # a map this young registers every scan (a moving start's replayed window: a 16-beam
# corridor's first scans 20-37 mm p95 with predicted scans among them, 1-8 mm without; at 10, a walk's standing
# start still had 4 predicted scans, which moved kiss-icp on the de-skewed walk from 1.9 to 5.9 m)
_MAX_BIAS_ACCEL_MPS2 = 3.0


class StateUpdates:
    """Priors, corrections and guards of ``LioOdometry``."""

    def _implausible(self, measured: np.ndarray, dirs_b: list) -> str | None:
        """A pose innovation far outside its covariance for several scans in a row (EKF only)."""
        fc = self.cfg.fusion
        if fc.method != "ekf":
            return None
        dirs_w = [self.state.R @ d for d in dirs_b]
        nis = pose_innovation_nis(self.state, measured, fc.rotation_sigma_rad,
                                  position_noise(fc.position_sigma_m, dirs_w, fc.degenerate_sigma_m))
        self._doubt = self._doubt + 1 if nis > _NIS_LIMIT else 0
        if self._doubt >= _NIS_SCANS:
            return f"prediction and registration disagreed for {self._doubt} scans (NIS {nis:.0f})"
        return None

    def _state_implausible(self) -> str | None:
        s = self.state
        speed = float(np.linalg.norm(s.v))
        if not (np.isfinite(s.v).all() and np.isfinite(s.bg).all() and np.isfinite(s.ba).all()):
            return "the IMU state became non-finite"
        if speed > self.cfg.max_speed_mps:
            return f"speed {speed:.1f} m/s beyond max_speed_mps"
        if np.linalg.norm(s.bg) > _MAX_BIAS_GYRO_RADPS or np.linalg.norm(s.ba) > _MAX_BIAS_ACCEL_MPS2:
            return f"IMU biases implausible (gyro {np.linalg.norm(s.bg):.2f} rad/s, accel {np.linalg.norm(s.ba):.2f} m/s^2)"
        return None

    def _registration_failed(self, measured: np.ndarray, guess: np.ndarray, gate_m: float | None = None) -> bool:
        """Non-finite, untouched (no correspondence at all), or implausibly far from the IMU prediction (further than
        ``gate_m`` too, for a prediction across a bridged gap registered with that gate)."""
        if not np.isfinite(measured).all():
            return True
        if self._reg.empty:
            return False
        if untouched(measured, guess):  # ICP returns the guess itself when nothing matched
            return True
        return exceeds_jump(measured, guess, max(_MAX_JUMP_M, gate_m or 0.0), _MAX_JUMP_RAD)

    def _guess(self, t_prev: int, t_ref: int) -> np.ndarray:
        prior = self.cfg.prior
        if prior == "imu":
            return self.state.pose()
        if prior == "constant-velocity":
            return self._last_pose @ self._last_delta
        if prior == "wheel":
            return self._last_pose @ self._wheel_delta(t_prev, t_ref)
        return self._last_pose.copy()

    def _wheel_speed(self, t_ns: int) -> float:
        twist = mean_twist(self._wheel, t_ns - 60_000_000, t_ns + 60_000_000) if self.cfg.use_wheel else None
        return np.nan if twist is None else twist[0]

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
        if twist == (0.0, 0.0) and np.linalg.norm(self.state.v) > _MOVING_MPS:
            self.stats.wheel_zero_skipped += 1  # an all-zero twist while moving: a pose source, not wheels
            return
        v_body = np.array([twist[0], 0.0, 0.0])
        fc = self.cfg.fusion
        if fc.method == "ekf":
            s = fc.wheel_speed_sigma_mps
            ekf_body_velocity_update(self.state, v_body, np.array([s, 2 * s, 2 * s]))
        else:
            complementary_velocity_update(self.state, v_body, fc.wheel_beta)
        self.stats.wheel_updates += 1

    def _correct(self, measured: np.ndarray, dirs_b: list[np.ndarray], dt_s: float) -> np.ndarray:
        fc = self.cfg.fusion
        dirs_w = [self.state.R @ d for d in dirs_b]
        if fc.method == "ekf":
            cov = position_noise(fc.position_sigma_m, dirs_w, fc.degenerate_sigma_m)
            ekf_pose_update(self.state, measured, fc.rotation_sigma_rad, cov)
        else:
            complementary_update(self.state, measured, fc.alpha, dt_s, self.ext.R_base_imu, dirs_w)
        if self.planar:
            flatten_planar(self.state)
        return self.state.pose()

    def _turning_slowly(self, imu: ImuBatch, t_prev: int, t_ref: int) -> bool:
        """Whether the IMU turns slower than ``slow_rate_degps`` over the scan's interval (not looked at, False,
        when no setting depends on it: lio odom's defaults)."""
        rc = self.cfg.registration
        if rc.steady_iterations is None and rc.slow_iterations is None and rc.slow_register_every == 1:
            return False
        lo, hi = np.searchsorted(imu.stamps_ns, (t_prev, t_ref))
        gyro = imu.gyro_radps[lo:hi + 1]  # the scan's interval (the window holds more on either side)
        return bool(len(gyro)) and bool(np.linalg.norm(gyro - self.state.bg, axis=1).max()
                                        < np.radians(rc.slow_rate_degps))

    def _icp_cap(self, slow: bool) -> int | None:
        """The ICP iterations of an IMU-primed scan whose prediction can be leant on (None: the full count).
        ``slow_iterations`` where the IMU turns slowly (``_turning_slowly``: the prediction is good there, a
        drive's ICP only slides along the road's surfaces in its later iterations, and such a scan cannot time
        the clock anyway); ``steady_iterations`` for any scan once the IMU clock is timed (or not tracked).
        A turning scan keeps full iterations while the clock tracker needs fully converged poses."""
        rc = self.cfg.registration
        if rc.steady_iterations is None and rc.slow_iterations is None:
            return None
        if slow:
            return rc.slow_iterations or rc.steady_iterations
        return rc.steady_iterations if self.clock is None or self.clock.done else None

    def _predicted_only(self, slow: bool) -> bool:
        """Whether this scan's pose is its IMU prediction, without registering it: of consecutive slowly turning
        scans only every ``slow_register_every``-th is registered (0.1 s of propagation from a state corrected
        one scan before is millimetres off; such a scan cannot time the clock anyway). Never in doubt, nor on a
        map of fewer than ``_PREDICT_MIN_MAP_SCANS`` scans (a start or a restart: the state just aligned from
        LiDAR-only scans, and the map needs every scan), nor unless the last degeneracy analysis found the scene
        clear (a corridor's accuracy moved with which scans were predicted); a predicted scan stays out of the map."""
        every = self.cfg.registration.slow_register_every
        if slow and every > 1 and self._predicted_run < every - 1 and not self._doubt and self._clear_scene \
                and self._reg is not None and self._reg.scans >= _PREDICT_MIN_MAP_SCANS:
            self._predicted_run += 1
            self.stats.predicted_scans += 1
            return True
        self._predicted_run = 0
        return False

    def _track_clock(self, t_ref: int, measured: np.ndarray, doubted: bool = False) -> None:
        if self.clock is None or self.clock.done:
            return
        self.clock.add_pose(t_ref, measured @ self.ext.T_base_lidar, doubted)
        delta = self.clock.propose(self.state.bg, self.stats.scans)
        if delta:
            self._shift_imu(delta)

    def _lidar_prior(self, t_prev: int, t_ref: int, imu_gap: bool = False):
        """(guess, deskew knots, knot poses): gyro rotation when the IMU can give it (it covers the interval without
        ``imu_gap``), else the configured prior."""
        dt = (t_ref - t_prev) * 1e-9
        if self.use_imu and self.imu_mounted and self._imu and self.imu_until_ns() >= t_ref and not imu_gap:
            v = np.zeros(3)  # world velocity of the last inter-scan motion: p_last - p_prev over its duration
            if self._last_dt_s > 0:
                v = self._last_pose[:3, :3] @ self._last_delta[:3, :3].T @ self._last_delta[:3, 3] / self._last_dt_s
            bg = np.zeros(3) if self._bias_prior[0] is None else np.asarray(self._bias_prior[0], dtype=np.float64)
            ba = np.zeros(3)
            s0 = NavState(t_prev, self._last_pose[:3, :3].copy(), self._last_pose[:3, 3].copy(), v, bg, ba)
            prop = propagate(s0, self._imu_window(t_prev), t_ref, self.ext, accel=False, planar=self.planar)
            guess = prop.poses[-1]
            if self.cfg.prior == "wheel":
                guess = self._last_pose @ self._wheel_delta(t_prev, t_ref)
            knots = (prop.stamps_ns, prop.poses) if self._deskew != "none" else (None, None)
            return guess, knots[0], knots[1], True
        cv = self._last_delta if self._last_dt_s <= 0 else scale_delta(self._last_delta, dt / self._last_dt_s)
        prior = self.cfg.prior
        guess = self._last_pose @ (self._wheel_delta(t_prev, t_ref) if prior == "wheel" else
                                   np.eye(4) if prior == "none" else cv)
        return (guess, *self._cv_knots(guess, t_prev, t_ref), False)

    def _cv_knots(self, guess: np.ndarray, t_prev: int, t_ref: int) -> tuple:
        """(knots, knot poses) de-skewing a scan by constant velocity from the last pose to ``guess``; (None, None)
        with ``deskew: none``."""
        if self._deskew == "none":
            return None, None
        knots, rel = constant_velocity_knots(inv_pose(self._last_pose) @ guess, t_prev, t_ref)
        return knots, self._last_pose[None] @ rel
