"""The estimators of ``lio calibrate`` in the order the command runs them, on what ``calibrate_passes`` read.

IMU at rest (the still stretch) -> time offset -> rotation (hand-eye on the gyro) -> lever arm (from
accelerations, refining the rotation) -> wheel scales; Allan on request. What an estimator cannot give is
either bad input (one line, exit 2: no still stretch where one is needed, clocks that do not overlap, an IMU
whose rotations match the LiDAR's at no offset) or an item not estimated, with its reason and the motion that
would show it (a clock offset or rotation the motion cannot pin, an axis it left unobservable, a missing
sensor): the rest is still estimated, and what later steps need of it is taken from the prior or zero.
"""

from __future__ import annotations

import re
from dataclasses import dataclass, field, replace

import numpy as np

from ...config.calibrate import CalibrateConfig
from ...core.calibration import (AllanResult, ImuStatic, LeverArmCalib, RotationCalib, TimeOffset, WheelCalib,
                                estimate_allan, estimate_imu_static, estimate_lever_arm, estimate_rotation,
                                estimate_time_offset, estimate_wheel_scales)
from ...core.calibration.clock_from_wheels import WheelClock, with_wheel_clock
from ...core.calibration.common import NS_PER_S, time_ranges_text
from ...core.calibration.imu_static import StillOptions, still_mask
from ...core.calibration.handeye import imu_increments, lidar_increments
from ...core.calibration.signals import GyroOrientation
from ...errors import InputError
from ...model.records import ImuBatch, on_lidar_clock
from .passes import LidarTrajectory, SensorArrays

FINAL_MAX_SIGMA_S = 0.002  # a clock offset known worse than this is refused (too little motion)
COARSE_MAX_SIGMA_S = 0.03  # the first estimates only start the gyro-primed passes
# ...and so does their rotation: an unprimed pass over brisk tilting motion scatters too much for the final 1 deg,
# while a mounting within a few degrees primes the next pass's de-skew well enough to sharpen it
COARSE_MAX_ROTATION_SIGMA_RAD = np.radians(5.0)
ROTATION_FROM_ACCEL_MAX_SIGMA_RAD = np.radians(1.0)  # an axis the lever arm's fit pins this well is estimated
CHECK_WINDOW_SCANS = 20  # about 2 s at 10 Hz
CHECK_REL_TOL = 0.25
CHECK_ABS_TOL_DEG = 5.0
LEVER_ARM = "the lever arm (T_base_imu translation)"
IMU_GAP_S = 0.05  # the IMU silent this long (and 5 sample intervals) is a gap...
IMU_GAP_MARGIN_S = 0.25  # ...whose scans, this far either side (a clock offset moves it), are left out


@dataclass
class Skipped:
    """A quantity not estimated: ``key`` names it in metrics (``not_estimated``), ``item`` in words."""

    item: str
    reason: str
    key: str

    def line(self) -> str:
        return f"not estimated: {self.item}: {self.reason}"


@dataclass
class Estimates:
    static: ImuStatic | None = None
    allan: AllanResult | None = None
    offset: TimeOffset | None = None
    rotation: RotationCalib | None = None
    lever: LeverArmCalib | None = None
    wheel: WheelCalib | None = None
    skipped: list[Skipped] = field(default_factory=list)
    notes: list[str] = field(default_factory=list)
    offset_assumed: bool = False  # the clock offset neither estimated nor given: zero was used, none is written
    wheel_clock: WheelClock | None = None  # the clock offset from the wheels' turns (``clock.wheel_clock``)

    def skip(self, key: str, item: str, reason: str) -> None:
        self.skipped.append(Skipped(item, reason.rstrip("."), key))

    def anything(self) -> bool:
        """Whether any quantity was estimated (else there is nothing to write)."""
        measured_offset = self.offset is not None and np.isfinite(self.offset.sigma_s)
        return any(x is not None for x in (self.static, self.allan, self.rotation, self.lever, self.wheel)) or \
            measured_offset

    def trial(self) -> Estimates:
        """A copy to estimate on, which can be dropped without touching this one's notes and skipped items."""
        return replace(self, skipped=list(self.skipped), notes=list(self.notes))


def imu_at_rest(imu: ImuBatch, still_ns: tuple[int, int] | None, needed: str | None, est: Estimates,
                where: str) -> None:
    """The still stretch's gyro bias, gravity, accelerometer bias along gravity and noise densities.
    ``needed``: why the still stretch is required (its absence is then bad input), None when optional."""
    if still_ns is not None:
        _check_still(imu, still_ns, where)
    try:
        est.static = estimate_imu_static(imu.stamps_ns, imu.gyro_radps, imu.accel_mps2, still_ns=still_ns)
    except InputError as err:
        if needed is not None or still_ns is not None:
            raise InputError(f"{where}: {err} ({needed or 'asked for with --still'})") from err
        est.skip("imu_at_rest", "the IMU at rest (accelerometer bias along gravity, noise densities)", str(err))
        return
    est.notes.extend(est.static.notes)


def _check_still(imu: ImuBatch, still_ns: tuple[int, int], where: str) -> None:
    """--still must name an interval where the IMU rests: else say where in it the IMU moves."""
    sel = (imu.stamps_ns >= still_ns[0]) & (imu.stamps_ns <= still_ns[1])
    if sel.sum() < 20:
        return  # the estimator says the interval is outside the data or too short
    s = imu.stamps_ns[sel]
    mask = still_mask(s, imu.gyro_radps[sel], imu.accel_mps2[sel], StillOptions())
    if mask.mean() < 0.9:
        t0 = int(imu.stamps_ns[0])
        raise InputError(f"{where}: --still {(still_ns[0] - t0) / 1e9:g}:{(still_ns[1] - t0) / 1e9:g} is not a still "
                         f"stretch: the IMU moves during {time_ranges_text(s, ~mask, t0)} (s after its first stamp); "
                         "name an interval where the platform stands still, or leave --still out to find one")


def allan(imu: ImuBatch, est: Estimates, where: str) -> None:
    try:
        est.allan = estimate_allan(imu.stamps_ns, imu.gyro_radps, imu.accel_mps2)
    except InputError as err:
        raise InputError(f"{where}: --allan: {err}") from err
    est.notes.extend(est.allan.notes)


def extrinsics(traj: LidarTrajectory, imu: ImuBatch, cfg: CalibrateConfig, est: Estimates, where: str,
               T_ref: np.ndarray | None, final: bool, prior_offset: float | None = None,
               floors: tuple | None = None) -> None:
    """Time offset, rotation and lever arm of the IMU against the LiDAR trajectory. ``final``: the last
    round (its notes and skipped items are the ones reported). ``T_ref``: the reference T_lidar_imu, whose
    translation holds the axes the motion does not show. ``prior_offset``: the clock offset given (--calib,
    --imu-time-offset), kept (and said so) when the motion cannot time the IMU; without it that is bad input.
    ``floors``: (rotation, lever arm, refined rotation) per-axis 1-sigmas not to report below (``floors_of``)."""
    bias0 = est.static.gyro_bias_radps if est.static is not None else None
    centre_ns = cfg.start_offset_ns  # the search spans +-max_offset_s around it
    traj, gap_note = without_imu_gaps(traj, imu, (est.offset.imu_time_offset_s if est.offset is not None
                                                  else centre_ns / NS_PER_S))
    if gap_note is not None and gap_note not in est.notes:
        est.notes.append(gap_note)
    try:
        off = estimate_time_offset(traj.stamps_ns, traj.T_world_lidar, on_lidar_clock(imu.stamps_ns, centre_ns),
                                   imu.gyro_radps, gyro_bias_radps=bias0, max_offset_s=cfg.max_offset_s,
                                   max_sigma_s=FINAL_MAX_SIGMA_S if final else COARSE_MAX_SIGMA_S)
        if centre_ns:
            off = replace(off, imu_time_offset_s=off.imu_time_offset_s + centre_ns / NS_PER_S)
    except InputError as err:
        if not str(err).startswith("too little"):
            raise InputError(f"{where}: {err}") from err  # clocks apart, or an IMU that is not this LiDAR's
        kept = centre_ns / NS_PER_S if prior_offset is None else prior_offset
        how = (f"kept as given ({1e3 * kept:+.3f} ms)" if prior_offset is not None else
               f"the other estimates use {1e3 * kept:+.3f} ms and the YAML holds none (give it with --imu-time-offset "
               "SECONDS or imu_time_offset_s in --calib if it is known)")
        off = _kept_offset(bias0, kept, f"{err}; {how}")
    if est.wheel_clock is not None:
        off = with_wheel_clock(off, est.wheel_clock)
    assumed = not np.isfinite(off.sigma_s) and prior_offset is None
    t_prior_lidar_m = None if T_ref is None else T_ref[:3, 3]
    try:
        rot = estimate_rotation(traj.stamps_ns, traj.T_world_lidar, imu.stamps_ns, imu.gyro_radps,
                                imu_time_offset_s=off.imu_time_offset_s,
                                gyro_bias_radps=bias0 if bias0 is not None else off.gyro_bias_radps,
                                sigma_floor_rad=None if floors is None else floors[0],
                                refuse_sigma_rad=None if final else COARSE_MAX_ROTATION_SIGMA_RAD)
    except InputError as err:
        if not final:
            raise InputError(f"{where}: {err}") from err
        est.offset, est.offset_assumed, est.rotation, est.lever = off, assumed, None, None
        _offset_skipped(off, est)
        est.skip("rotation", "the IMU's mounting rotation (T_base_imu)", str(err))
        est.skip("lever_arm", "the lever arm (T_base_imu translation)", "it is measured through the mounting rotation, "
                 "which was not estimated")
        return
    est.offset, est.offset_assumed, est.rotation = off, assumed, rot
    try:
        est.lever = estimate_lever_arm(
            traj.stamps_ns, traj.T_world_lidar, imu.stamps_ns, imu.gyro_radps, imu.accel_mps2,
            R_lidar_imu=rot.R_lidar_imu, rotation_covariance_rad2=rot.fit_covariance_rad2,
            imu_time_offset_s=off.imu_time_offset_s, gyro_bias_radps=rot.gyro_bias_radps, t_prior_m=t_prior_lidar_m,
            sigma_floor_m=None if floors is None else floors[1],
            rotation_sigma_floor_rad=None if floors is None else floors[2])
    except InputError as err:
        est.lever = None
        if final:
            est.skip("lever_arm", LEVER_ARM, f"{err}; {_lever_kept(T_ref)}")
    if not final:
        return
    _offset_skipped(off, est)
    lever = est.lever
    for note in (*(off.notes if np.isfinite(off.sigma_s) else ()), *rot.notes, *(lever.notes if lever is not None else ())):
        if "not observable" not in note:
            est.notes.append(note)
            continue
        key, item = _unobservable_item(note)
        k = "xyz".find(key[-1]) if key.startswith("rotation_") else -1
        if k >= 0 and lever is not None and lever.rotation_sigma_rad[k] <= ROTATION_FROM_ACCEL_MAX_SIGMA_RAD:
            est.notes.append(f"{note.split(' (1-sigma')[0]} alone; the accelerations measure it (1-sigma "
                             f"{np.degrees(lever.rotation_sigma_rad[k]):.2f} deg)")
        else:
            why = note[len(item):].strip().removeprefix("is ").removeprefix("are ")
            est.skip(key, item, f"{why}; {_lever_kept(T_ref)}" if key == "lever_arm" else why)


def _lever_kept(T_ref: np.ndarray | None) -> str:
    return ("the translation is kept from the prior" if T_ref is not None else
            "the translation is left at zero (no /tf_static or --calib holds one)")


def _offset_skipped(off: TimeOffset, est: Estimates) -> None:
    if not np.isfinite(off.sigma_s):
        est.skip("imu_time_offset_s", "the LiDAR-IMU clock offset", off.notes[0])


def floors_of(est: Estimates) -> tuple:
    """The 1-sigmas of ``est`` as floors for estimates on a sharper trajectory of the same log whose poses'
    errors are shared (the map rounds): its values may move, its uncertainty is not claimed smaller."""
    lever = est.lever
    return (est.rotation.sigma_rad, None if lever is None else lever.sigma_m,
            None if lever is None else lever.rotation_sigma_rad)


def _kept_offset(bias: np.ndarray | None, offset_s: float, why: str) -> TimeOffset:
    """A TimeOffset holding the given offset (the motion could not time the IMU: ``why``, its only note)."""
    return TimeOffset(imu_time_offset_s=float(offset_s), sigma_s=float("nan"), alignment=float("nan"),
                      R_lidar_imu=np.eye(3), gyro_bias_radps=np.zeros(3) if bias is None else np.asarray(bias),
                      intervals=0, rms_residual_rad=float("nan"), notes=(why,))


def imu_gaps(imu: ImuBatch) -> list[tuple[int, int]]:
    """(last stamp before, first stamp after) of every stretch the IMU is silent for ``IMU_GAP_S`` and five of
    its sample intervals."""
    dt = np.diff(imu.stamps_ns)
    if not len(dt):
        return []
    gap = np.flatnonzero(dt > max(IMU_GAP_S * NS_PER_S, 5.0 * float(np.median(dt))))
    return [(int(imu.stamps_ns[k]), int(imu.stamps_ns[k + 1])) for k in gap]


def without_imu_gaps(traj: LidarTrajectory, imu: ImuBatch, offset_s: float) -> tuple[LidarTrajectory, str | None]:
    """The trajectory without its scans over an IMU gap (the gyro and accelerometer interpolated across one are
    fiction), and a note when a gap lies under the trajectory (None: none does). The note does not
    depend on what an earlier call already took out, so every pass gives the same one."""
    s, margin = traj.stamps_ns, int(IMU_GAP_MARGIN_S * NS_PER_S)
    shift = int(round(offset_s * NS_PER_S))  # IMU stamp + offset = LiDAR time
    gaps = [(a, b) for a, b in imu_gaps(imu) if len(s) and a + shift - margin <= s[-1] and b + shift + margin >= s[0]]
    if not gaps:
        return traj, None
    out = np.zeros(len(s), bool)
    for a, b in gaps:
        out |= (s >= a + shift - margin) & (s <= b + shift + margin)
    t0 = int(imu.stamps_ns[0])
    where = ", ".join(f"{(b - a) / NS_PER_S:.2f} s at {(a - t0) / NS_PER_S:.1f}-{(b - t0) / NS_PER_S:.1f} s"
                      for a, b in gaps[:4]) + (f" and {len(gaps) - 4} more" if len(gaps) > 4 else "")
    note = (f"the IMU has {len(gaps)} gap{'s' if len(gaps) > 1 else ''} ({where} after its first stamp): the scans "
            f"over {'them' if len(gaps) > 1 else 'it'} and {IMU_GAP_MARGIN_S:g} s either side are left out of the "
            "LiDAR-IMU estimates")
    if out.any():
        traj = LidarTrajectory(s[~out], traj.T_world_lidar[~out], int((~out).sum()), traj.scans_total,
                               f"{traj.description}; {_scans(int(out.sum()))} over IMU gaps left out")
    return traj, note


def consistent_scans(traj: LidarTrajectory, imu: ImuBatch, offset_s: float, bias: np.ndarray | None,
                     window: int = CHECK_WINDOW_SCANS) -> tuple[LidarTrajectory, int]:
    """The LiDAR-only trajectory without the stretches where it lost track: over every ``window`` scan
    intervals the angle the LiDAR turned must match the gyro's (angles do not depend on the mounting, and a
    window of seconds hardly on a clock offset of up to 0.1 s). Returns (trajectory kept, scans left out)."""
    traj, _ = without_imu_gaps(traj, imu, offset_s)
    s, P = traj.stamps_ns, traj.T_world_lidar
    if len(s) < window + 2:
        return traj, 0
    gyro = GyroOrientation(imu.stamps_ns, imu.gyro_radps, bias)
    ia, ib = np.arange(len(s) - 1), np.arange(1, len(s))
    ang_l = np.linalg.norm(lidar_increments(P, ia, ib), axis=1)
    ang_g = np.linalg.norm(imu_increments(gyro, s[ia], s[ib], offset_s), axis=1)
    k = np.ones(window)
    sum_l, sum_g = np.convolve(ang_l, k, "valid"), np.convolve(ang_g, k, "valid")
    bad_win = np.abs(sum_l - sum_g) > CHECK_REL_TOL * sum_g + np.radians(CHECK_ABS_TOL_DEG)
    bad_int = np.convolve(bad_win.astype(float), k, "full")[: len(ang_l)] > 0  # an interval in any bad window
    bad_pose = np.zeros(len(s), bool)
    bad_pose[:-1] |= bad_int
    bad_pose[1:] |= bad_int
    if bad_pose.all() or not bad_pose.any():
        return traj, 0
    keep = ~bad_pose
    kept = LidarTrajectory(s[keep], P[keep], int(keep.sum()), traj.scans_total,
                           f"{traj.description}; {_scans(int(bad_pose.sum()))} where it disagreed with the gyro's "
                           "turn angles left out")
    return kept, int(bad_pose.sum())


def _unobservable_item(note: str) -> tuple[str, str]:
    """(key, item) of an estimator's note: ('lever_arm_z', 'the lever arm along the LiDAR z axis'),
    ('rotation_x', "the mounting's rotation about the LiDAR x axis"); another direction than an axis keeps its
    words as the key."""
    head = note.split(" is not observable")[0].split(" are not observable")[0]
    if head == LEVER_ARM:
        return "lever_arm", head
    axis = re.search(r"the LiDAR ([xyz]) axis$", head)
    kind = "lever_arm" if head.startswith("the lever arm") else "rotation"
    direction = head.rsplit("direction ", 1)[-1].replace(" ", "")
    return (f"{kind}_{axis.group(1)}" if axis else f"{kind}_about_{direction}"), head


def wheels(arrays: SensorArrays, traj: LidarTrajectory, T_base_lidar: np.ndarray, cfg: CalibrateConfig,
           est: Estimates, where: str, against: str | None = None) -> None:
    """Wheel scales against ``traj``; ``against``: a note on why that trajectory, kept when they are measured."""
    if not arrays.has_wheels:
        est.skip("wheel_scales", "the wheel odometry scales", "the log has no wheel odometry")
        return
    try:
        est.wheel = estimate_wheel_scales(
            arrays.wheel_stamps_ns, arrays.wheel_linear_mps, arrays.wheel_angular_radps, traj.stamps_ns,
            traj.T_world_lidar, T_base_traj=T_base_lidar, radius_m=cfg.wheel_radius_m,
            baseline_m=cfg.wheel_baseline_m)
    except InputError as err:
        est.skip("wheel_scales", "the wheel odometry scales", str(err))
        return
    if against:
        est.notes.append(against)
    est.notes.extend(est.wheel.notes)


def _scans(n: int) -> str:
    return f"{n} scan{'s' * (n != 1)}"


__all__ = ["Estimates", "Skipped", "allan", "consistent_scans", "extrinsics", "imu_at_rest", "wheels"]
