"""A ground vehicle's IMU roll and pitch on its base from the planar-motion constraint, joined to what hand-eye
and the accelerations gave (``core.calibration.ground_plane``).

Hand-eye reads a car's roll and pitch from LiDAR rotations that follow only part of the body's sway; the gyro
alone, carried through a whole drive, shows them against the turns. The two are combined by their information
(the sharper one dominates: the gyro on a car, a fused 2D scanner's passes on a robot).
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from ...core.calibration.ground_plane import BIAS_PRIOR_RADPS, estimate_planar_tilt
from ...core.calibration.rotation import RotationCalib
from ...core.calibration.yaw_from_wheels import estimate_wheel_yaw
from ...errors import InputError
from ...geometry import so3_exp
from ...model.records import ImuBatch
from .estimate import Estimates
from .passes import SensorArrays
from .report import MAX_ROTATION_SIGMA_RAD, T_lidar_imu_of, rotation_cov_lidar, rotation_observable

MIN_YAW_ACCEL_MPS2 = 0.5  # rms horizontal acceleration below which the planar fit's yaw is not used
SHARPER = 3.0  # hand-eye's roll or pitch this many times sharper than the planar fit's: not joined


def ground_rotation(arrays: SensorArrays, imu: ImuBatch, T_base_lidar: np.ndarray | None, T_ref: np.ndarray | None,
                    est: Estimates) -> None:
    """Roll and pitch on the base from planar motion: joined to hand-eye's, or, where hand-eye gave no rotation
    (a car turning about one axis), the whole mounting's start (its yaw a first guess from the wheels, which
    ``ground.wheel_yaw`` then measures)."""
    if est.rotation is None:
        _without_hand_eye(arrays, imu, T_base_lidar, est)
    else:
        planar_tilt(arrays, imu, T_base_lidar, T_ref, est, arrays.has_wheels)


def _without_hand_eye(arrays: SensorArrays, imu: ImuBatch, T_base_lidar: np.ndarray | None, est: Estimates) -> None:
    """The mounting from gravity (its up, at rest or averaged), the planar-motion tilt and the wheels' yaw, for a
    ground vehicle whose rotations hand-eye could not use."""
    if T_base_lidar is None or not arrays.has_wheels or est.wheel is None or est.offset is None:
        return
    up = est.static.up_imu if est.static is not None else imu.accel_mps2.mean(axis=0)
    up = up / np.linalg.norm(up)
    R = _align(up)  # R_base_imu with the base z on up, its yaw arbitrary
    bias = est.static.gyro_bias_radps if est.static is not None else None
    w = est.wheel
    try:  # the yaw first (the accelerometer's sway is read through it), then the roll and pitch
        yaw = estimate_wheel_yaw(arrays.wheel_stamps_ns, *w.corrected(arrays.wheel_linear_mps, arrays.wheel_angular_radps),
                                 imu.stamps_ns, imu.accel_mps2, R_base_imu=R,
                                 imu_time_offset_s=est.offset.imu_time_offset_s, exclude_ns=w.slip_ns)
        R = so3_exp(np.array([0.0, 0.0, yaw.yaw_rad])) @ R
        corr, tilt = _planar_fit(arrays, imu, R, bias, None, est)
        R = so3_exp(corr) @ R
    except InputError as err:
        est.notes.append(f"the mounting without hand-eye (a ground vehicle's gravity, turns and wheels): {err}")
        return
    if (tilt.sigma_rad > MAX_ROTATION_SIGMA_RAD).any():
        est.notes.append(f"the mounting without hand-eye: roll and pitch from planar motion at 1-sigma "
                         f"{_deg(tilt.sigma_rad)} deg (the heading changed {np.degrees(tilt.heading_spread_rad):.0f} deg; "
                         "turn both ways, 90 deg or more)")
        return
    Rbl = np.asarray(T_base_lidar, float)[:3, :3]
    if _yaw_usable(tilt):
        C = tilt.covariance3_rad2
    else:
        C = np.zeros((3, 3))
        C[:2, :2] = tilt.covariance_rad2
        C[2, 2] = np.pi**2  # the yaw is a first guess until ``wheel_yaw`` measures it
    cov = Rbl.T @ C @ Rbl
    sig = np.sqrt(np.clip(np.diag(cov), 0, None))
    g0 = np.zeros(3) if bias is None else np.asarray(bias, float)
    est.rotation = RotationCalib(R_lidar_imu=Rbl.T @ R, sigma_rad=sig, covariance_rad2=cov,
                                 observable=sig <= MAX_ROTATION_SIGMA_RAD, gyro_bias_radps=g0,
                                 gyro_bias_sigma_radps=np.full(3, np.nan), windows=0,
                                 rms_residual_rad=tilt.rms_sway_rad, notes=(), registration_gain=np.zeros((3, 3)),
                                 fit_covariance_rad2=cov)
    dropped = [s for s in est.skipped if s.key == "rotation"]
    est.skipped = [s for s in est.skipped if s.key != "rotation"]
    for k in np.flatnonzero(~est.rotation.observable):
        est.skip(f"rotation_{'xyz'[k]}", f"the mounting's rotation about the LiDAR {'xyz'[k]} axis",
                 "hand-eye could not use the rotations" + (f" ({dropped[0].reason})" if dropped else "") +
                 "; gravity and the turns give the roll and pitch on the base, not the rotation about its vertical")
    est.notes.append(f"the mounting without hand-eye: roll and pitch on the base from planar motion, 1-sigma "
                     f"{_deg(tilt.sigma_rad)} deg (heading changed {np.degrees(tilt.heading_spread_rad):.0f} deg, sway "
                     f"{np.degrees(tilt.rms_sway_rad):.2f} deg rms); the yaw from the accelerations, 1-sigma "
                     f"{np.degrees(tilt.yaw_sigma_rad):.2f} deg")


def _accel_args(arrays: SensorArrays, imu: ImuBatch, est: Estimates) -> dict:
    """The accelerometer and the scaled wheels, to take the body's sway out (none without wheel scales)."""
    w = est.wheel
    if w is None or est.offset is None:
        return {}
    wheels = (arrays.wheel_stamps_ns, *w.corrected(arrays.wheel_linear_mps, arrays.wheel_angular_radps))
    return {"accel_mps2": imu.accel_mps2, "wheels": wheels, "imu_time_offset_s": est.offset.imu_time_offset_s,
            "exclude_ns": w.slip_ns}


def _align(up: np.ndarray) -> np.ndarray:
    """The smallest rotation taking ``up`` onto the z axis."""
    ez = np.array([0.0, 0.0, 1.0])
    axis = np.cross(up, ez)
    n = np.linalg.norm(axis)
    if n < 1e-12:
        return np.eye(3) if up[2] > 0 else np.diag([1.0, -1.0, -1.0])
    return so3_exp(axis / n * np.arctan2(n, float(up @ ez)))


def planar_tilt(arrays: SensorArrays, imu: ImuBatch, T_base_lidar: np.ndarray | None, T_ref: np.ndarray | None,
                est: Estimates, ground_vehicle: bool) -> None:
    """Join the planar-motion roll and pitch (and, with wheels, the yaw the accelerations show) to ``est``'s
    mounting when the motion was planar (the vertical stays put in the base frame); ``ground_vehicle`` (it has
    wheels): say why when it could not."""
    if est.rotation is None or T_base_lidar is None:
        return
    Rbl = np.asarray(T_base_lidar, float)[:3, :3]
    R_lidar_imu = T_lidar_imu_of(est, T_ref)[:3, :3]
    try:
        corr, res = _loose_bias_fit(arrays, imu, Rbl @ R_lidar_imu, est)
    except InputError as err:
        if ground_vehicle:
            est.notes.append(f"the mounting's roll and pitch on the base: {err}")
        return
    if (res.sigma_rad > MAX_ROTATION_SIGMA_RAD).any():
        if ground_vehicle:
            est.notes.append(f"roll and pitch from planar motion: 1-sigma {_deg(res.sigma_rad)} deg, not used (the heading "
                             f"changed {np.degrees(res.heading_spread_rad):.0f} deg; turn both ways, 90 deg or more)")
        return
    with_yaw = _yaw_usable(res)
    he = np.sqrt(np.clip(np.diag(Rbl @ rotation_cov_lidar(est) @ Rbl.T), 0, None))[:2]
    if not with_yaw and (SHARPER * he <= res.sigma_rad).any():
        # hand-eye's already far sharper (a 2D scanner's fused passes): joining would only carry the fit's bias in
        est.notes.append(f"roll and pitch from planar motion (1-sigma {_deg(res.sigma_rad)} deg) left out: hand-eye's "
                         f"are sharper ({_deg(he)} deg)")
        return
    before = rotation_observable(est)
    # the measurement: the base-frame correction ``corr`` (about x, y and, when the yaw is sharp enough, z)
    B = Rbl if with_yaw else Rbl[:2]  # base axes in the LiDAR frame: B d = corr for a correction exp(d) (LiDAR frame)
    Si = np.linalg.inv(res.covariance3_rad2 if with_yaw else res.covariance_rad2)
    info = np.linalg.inv(rotation_cov_lidar(est)) + B.T @ Si @ B
    cov = np.linalg.inv(info)
    d = cov @ (B.T @ Si @ (corr if with_yaw else corr[:2]))
    R_new = so3_exp(d) @ R_lidar_imu
    sig = np.sqrt(np.clip(np.diag(cov), 0, None))
    rot = est.rotation
    est.rotation = replace(rot, R_lidar_imu=R_new, covariance_rad2=cov, sigma_rad=sig,
                           observable=sig <= MAX_ROTATION_SIGMA_RAD)
    if est.lever is not None:
        lev = est.lever
        refined = np.isfinite(lev.rotation_covariance_rad2).all()
        est.lever = replace(lev, R_lidar_imu=R_new, rotation_covariance_rad2=cov if refined else
                            lev.rotation_covariance_rad2, rotation_sigma_rad=sig if refined else lev.rotation_sigma_rad)
    now = rotation_observable(est)
    gained = {f"rotation_{'xyz'[k]}" for k in np.flatnonzero(now & ~before)}
    if now.all():
        gained |= {s.key for s in est.skipped if s.key.startswith("rotation_about_")}
    est.skipped = [s for s in est.skipped if s.key not in gained]
    yaw = (f"; the yaw the accelerations show {np.degrees(corr[2]):+.2f} deg, 1-sigma {np.degrees(res.yaw_sigma_rad):.2f}"
           if with_yaw else "")
    est.notes.append(f"the mounting's roll and pitch on the base from planar motion (the gyro's turns about the base "
                     f"z): {_deg(corr[:2], signed=True)} deg from hand-eye's, 1-sigma {_deg(res.sigma_rad)} deg "
                     f"(heading changed {np.degrees(res.heading_spread_rad):.0f} deg, sway {np.degrees(res.rms_sway_rad):.2f} "
                     f"deg rms){yaw}; joined by their information")


def _loose_bias_fit(arrays: SensorArrays, imu: ImuBatch, R_base_imu: np.ndarray, est: Estimates):
    """``_planar_fit`` with the gyro bias's prior loosened in the base plane (``_bias_prior_sigma``); how far
    that moved the correction from the fit under hand-eye's prior joins its covariance (per base axis, squared)."""
    rot = est.rotation
    corr, res = _planar_fit(arrays, imu, R_base_imu, rot.gyro_bias_radps,
                            _bias_prior_sigma(rot.gyro_bias_sigma_radps, R_base_imu), est)
    try:
        tight, _ = _planar_fit(arrays, imu, R_base_imu, rot.gyro_bias_radps, rot.gyro_bias_sigma_radps, est)
    except InputError:
        return corr, res
    extra = (corr - tight) ** 2
    C = res.covariance_rad2 + np.diag(extra[:2])
    C3 = None if res.covariance3_rad2 is None else res.covariance3_rad2 + np.diag(extra)
    return corr, replace(res, covariance_rad2=C, sigma_rad=np.sqrt(np.clip(np.diag(C), 0, None)), covariance3_rad2=C3,
                         yaw_sigma_rad=float(np.sqrt(res.yaw_sigma_rad**2 + extra[2])))


def _bias_prior_sigma(sigma_radps: np.ndarray, R_base_imu: np.ndarray) -> np.ndarray:
    """The gyro bias's 1-sigma the planar fit takes as its prior: hand-eye's about the base z (the turns time it),
    ``BIAS_PRIOR_RADPS`` added by each IMU axis's share of the base plane (a car's hand-eye put that part of the
    bias up to 5.6 of its 1-sigmas off on simulated moving starts)."""
    horizontal = 1.0 - np.asarray(R_base_imu, float)[2] ** 2  # per IMU axis: its squared share of the base x-y
    s = np.nan_to_num(np.asarray(sigma_radps, float), nan=BIAS_PRIOR_RADPS)
    return np.sqrt(s**2 + BIAS_PRIOR_RADPS**2 * np.clip(horizontal, 0.0, 1.0))


def _yaw_usable(res) -> bool:
    """Whether the planar fit's yaw is used: its 1-sigma within 1 deg, from accelerations of ``MIN_YAW_ACCEL_MPS2``
    (a ground robot's 0.2 m/s^2 left it 1.5-2.4 deg off at 1-sigma 0.3-0.7: the wheels' own fit takes it then)."""
    return res.covariance3_rad2 is not None and res.yaw_sigma_rad <= MAX_ROTATION_SIGMA_RAD and \
        res.rms_accel_mps2 >= MIN_YAW_ACCEL_MPS2


def _planar_fit(arrays: SensorArrays, imu: ImuBatch, R_base_imu: np.ndarray, bias, bias_sigma, est: Estimates):
    """The planar fit twice, the second from the first's correction (its yaw can be degrees: linearised);
    returns (the base-frame correction (x, y, z) of both, the second's result)."""
    corr = np.zeros(3)
    R = R_base_imu
    for _ in range(2):
        res = estimate_planar_tilt(imu.stamps_ns, imu.gyro_radps, R_base_imu=R, gyro_bias_radps=bias,
                                   gyro_bias_sigma_radps=bias_sigma, **_accel_args(arrays, imu, est))
        step = np.array([*-res.tilt_rad, res.yaw_rad if np.isfinite(res.yaw_rad) else 0.0])
        R = so3_exp(step) @ R
        corr = corr + step
    return corr, res


def _deg(v: np.ndarray, signed: bool = False) -> str:
    return "/".join(f"{np.degrees(x):{'+' if signed else ''}.2f}" for x in v)
