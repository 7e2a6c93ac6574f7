"""Guards of the scan steps: whether a registration failed, whether the IMU state still explains the scans and
is plausible, when the track is lost for good; and how much a slowly turning scan leans on its prediction."""

from __future__ import annotations

import numpy as np

from ...config.odom import FusionConfig, RegistrationConfig
from ...model.records import ImuBatch
from ..imu import NavState
from .clock_offset import ClockOffsetTracker
from .filter import pose_innovation_nis, position_noise
from .pose_checks import exceeds_jump, untouched
from .state import Diverged, Health, OdomStats, Track
from .tuning import (MAX_BIAS_ACCEL_MPS2, MAX_BIAS_GYRO_RADPS, MAX_JUMP_M, MAX_JUMP_RAD, NIS_LIMIT, NIS_SCANS,
                     PREDICT_MIN_MAP_SCANS)


def registration_failed(measured: np.ndarray, guess: np.ndarray, map_empty: bool, gate_m: float | None = None) -> bool:
    """Non-finite, untouched (no correspondence at all), or implausibly far from the IMU prediction (further than
    ``gate_m`` too, for a prediction across a bridged gap registered with that gate)."""
    if not np.isfinite(measured).all():
        return True
    if map_empty:
        return False
    if untouched(measured, guess):  # ICP returns the guess itself when nothing matched
        return True
    return exceeds_jump(measured, guess, max(MAX_JUMP_M, gate_m or 0.0), MAX_JUMP_RAD)


def implausible(state: NavState, measured: np.ndarray, dirs_b: list, fc: FusionConfig,
                doubt: int) -> tuple[int, str | None]:
    """(scans in a row now doubted, why the state no longer explains the scans or None): a pose innovation far
    outside its covariance for ``NIS_SCANS`` scans in a row (EKF only; ``doubt``: the count before this scan)."""
    if fc.method != "ekf":
        return doubt, None
    dirs_w = [state.R @ d for d in dirs_b]
    nis = pose_innovation_nis(state, measured, fc.rotation_sigma_rad,
                              position_noise(fc.position_sigma_m, dirs_w, fc.degenerate_sigma_m))
    doubt = doubt + 1 if nis > NIS_LIMIT else 0
    if doubt >= NIS_SCANS:
        return doubt, f"prediction and registration disagreed for {doubt} scans (NIS {nis:.0f})"
    return doubt, None


def state_implausible(s: NavState, max_speed_mps: float) -> str | None:
    """Why the IMU state is no longer plausible (non-finite, too fast, biases too large), or None."""
    speed = float(np.linalg.norm(s.v))
    if not (np.isfinite(s.v).all() and np.isfinite(s.bg).all() and np.isfinite(s.ba).all()):
        return "the IMU state became non-finite"
    if speed > max_speed_mps:
        return f"speed {speed:.1f} m/s beyond max_speed_mps"
    if np.linalg.norm(s.bg) > MAX_BIAS_GYRO_RADPS or np.linalg.norm(s.ba) > MAX_BIAS_ACCEL_MPS2:
        return f"IMU biases implausible (gyro {np.linalg.norm(s.bg):.2f} rad/s, accel {np.linalg.norm(s.ba):.2f} m/s^2)"
    return None


def count_lost(health: Health, max_lost_scans: int, scan: int, t_ref: int) -> None:
    """One more scan in a row that no registration could place; ``max_lost_scans`` end the run."""
    health.lost += 1
    if health.lost >= max_lost_scans:
        raise Diverged(f"lost track at scan {scan} (stamp {t_ref * 1e-9:.3f} s): no registration, "
                       f"IMU-primed or LiDAR-only, could place {health.lost} scans in a row")


def turning_slowly(imu: ImuBatch, t_prev: int, t_ref: int, gyro_bias: np.ndarray, rc: RegistrationConfig) -> bool:
    """Whether the IMU turns slower than ``slow_rate_degps`` over the scan's interval (not looked at, False, when no
    setting depends on it: lio odom's defaults)."""
    if rc.steady_iterations is None and rc.slow_iterations is None and rc.slow_register_every == 1:
        return False
    lo, hi = np.searchsorted(imu.stamps_ns, (t_prev, t_ref))
    gyro = imu.gyro_radps[lo:hi + 1]  # the scan's interval (the window holds more on either side)
    return bool(len(gyro)) and bool(np.linalg.norm(gyro - gyro_bias, axis=1).max()
                                    < np.radians(rc.slow_rate_degps))


def icp_cap(slow: bool, rc: RegistrationConfig, clock: ClockOffsetTracker | None) -> int | None:
    """ICP iterations of an IMU-primed scan whose prediction can be leant on (None: the full count):
    ``slow_iterations`` where the IMU turns slowly, ``steady_iterations`` for any scan once the IMU clock is timed
    (or not tracked); a turning scan keeps full iterations while the clock tracker needs converged poses."""
    if rc.steady_iterations is None and rc.slow_iterations is None:
        return None
    if slow:
        return rc.slow_iterations or rc.steady_iterations
    return rc.steady_iterations if clock is None or clock.done else None


def predicted_only(slow: bool, every: int, track: Track, doubt: int, clear_scene: bool, map_scans: int,
                   stats: OdomStats) -> bool:
    """Whether this scan's pose is its IMU prediction, unregistered: of consecutive slowly turning scans only every
    ``every``-th is registered; never in doubt, on a map of fewer than ``PREDICT_MIN_MAP_SCANS`` scans, nor unless
    the last degeneracy analysis found the scene clear."""
    if slow and every > 1 and track.predicted_run < every - 1 and not doubt and clear_scene \
            and map_scans >= PREDICT_MIN_MAP_SCANS:
        track.predicted_run += 1
        stats.predicted_scans += 1
        return True
    track.predicted_run = 0
    return False
