"""From estimates to what ``lio calibrate`` hands out: the calibration (the YAML ``--calib`` reads) and the
table of each value, its 1-sigma and its difference from the reference (``--calib`` when given, else
/tf_static). Units of the table: degrees for rotations, centimetres for translations, milliseconds for the
clock offset; SI with the unit named otherwise.
"""

from __future__ import annotations

import numpy as np

from ...core.calibration.excitation import dominant_rotation_axis, turned_mostly_about
from ...core.calibration.handeye import lidar_increments
from ...geometry import inv_pose, make_pose, so3_exp, so3_log
from ...model.calibration import ARBITRARY_SIGMA_RAD, MAX_LEVER_ARM_M, Calibration, ImuNoiseCalibration, WheelCalibration
from ...model.calibration import MAX_ROTATION_SIGMA_RAD as ROTATION_SIGMA_CAP_RAD
from .estimate import Estimates

AXES = ("x", "y", "z")
MAX_ACCEL_BIAS_SIGMA_MPS2 = 0.05  # a vaguer 3-axis bias is not written (odom would start from it)
REFERENCE_AGREES_SIGMAS = 3.0
MAX_ROTATION_SIGMA_RAD = np.radians(1.0)  # the rotation estimator's own threshold of an observable axis
PRECISE_ROTATION_RAD = np.radians(0.2)  # an observable axis with a larger 1-sigma gets a note saying how to move
PRECISE_TRANSLATION_M = 0.02


def rotation_observable(est: Estimates) -> np.ndarray:
    """Per LiDAR axis: does the rotation estimate (refined by the lever arm when it ran) pin it?"""
    obs = est.rotation.observable.copy()
    if est.lever is not None:
        sig = est.lever.rotation_sigma_rad
        obs |= np.isfinite(sig) & (sig <= MAX_ROTATION_SIGMA_RAD)
    return obs


def T_lidar_imu_of(est: Estimates, T_ref: np.ndarray | None) -> np.ndarray | None:
    """The IMU mounting in the LiDAR frame: the lever arm's refined rotation (else the gyro's) and its
    translation, each on the axes the motion showed; the others from the reference ``T_ref`` (T_lidar_imu
    of /tf_static or --calib) when there is one (a rotation where the reference agrees with the weak estimate
    within 3 sigma or the estimate's 1-sigma exceeds 2.5 deg), else the estimate's rotation and a zero translation."""
    if est.rotation is None:
        return None
    R = est.rotation.R_lidar_imu
    if est.lever is not None:  # the accelerations' refinement, on the axes it pins (elsewhere it is a guess)
        d = so3_log(est.lever.R_lidar_imu @ R.T)
        d[~(np.isfinite(est.lever.rotation_sigma_rad) & (est.lever.rotation_sigma_rad <= MAX_ROTATION_SIGMA_RAD))] = 0.0
        R = so3_exp(d) @ R
    t = np.zeros(3) if T_ref is None else np.asarray(T_ref[:3, 3], float).copy()
    if est.lever is not None:
        t[est.lever.observable] = est.lever.t_lidar_imu_m[est.lever.observable]
    obs = rotation_observable(est)
    if T_ref is not None and not obs.all():
        d = so3_log(R @ T_ref[:3, :3].T)  # R = exp(d) R_ref, d about the LiDAR axes
        sig = np.sqrt(np.clip(np.diag(rotation_cov_lidar(est)), 0, None))
        # a reference the data contradicts is not kept, unless the data hardly constrain that axis at all
        agree = (np.abs(d) <= REFERENCE_AGREES_SIGMAS * sig) | (sig > ARBITRARY_SIGMA_RAD)
        d[~obs & agree] = 0.0
        R = so3_exp(d) @ T_ref[:3, :3]
    return make_pose(R, t)


def imprecision_notes(est: Estimates, T_world_lidar: np.ndarray) -> list[str]:
    """A note for each axis the motion showed, but not to the precision a LiDAR-IMU pipeline wants
    (``PRECISE_ROTATION_RAD``, ``PRECISE_TRANSLATION_M``), with what would show it better: turning about other
    axes than the one the platform mostly turned about (a walk's yaw sweeps show the mounting's rotation about
    the vertical and the vertical lever arm only through its small roll and pitch), else a longer recording."""
    if est.rotation is None:
        return []
    step = np.arange(len(T_world_lidar) - 1)
    axis, share = dominant_rotation_axis(lidar_increments(T_world_lidar, step, step + 1))
    notes = []

    def add(what: str, k: int, sigma: str) -> None:
        if turned_mostly_about(np.eye(3)[k], axis, share):
            how = (f"the platform turned mostly about that axis ({100 * share:.0f}% of its rotation): tilt and roll the "
                   f"sensor (+-10-20 deg) while recording (a vehicle: drive over ramps and bumps)")
        else:
            how = "record longer (a minute or more) or turn the sensor more briskly about the other axes"
        notes.append(f"{what} the LiDAR {AXES[k]} axis is measured to 1-sigma {sigma} only: {how}")

    rot_sigma = np.sqrt(np.diag(rotation_cov_lidar(est)))
    for k in np.flatnonzero(rotation_observable(est) & (rot_sigma > PRECISE_ROTATION_RAD)):
        add("the mounting's rotation about", k, f"{np.degrees(rot_sigma[k]):.2f} deg")
    if est.lever is not None:
        for k in np.flatnonzero(est.lever.observable & (est.lever.sigma_m > PRECISE_TRANSLATION_M)):
            add("the lever arm along", k, f"{100 * est.lever.sigma_m[k]:.1f} cm")
    return notes


def rotation_cov_lidar(est: Estimates) -> np.ndarray:
    if est.lever is not None and np.isfinite(est.lever.rotation_covariance_rad2).all():
        return est.lever.rotation_covariance_rad2
    return est.rotation.covariance_rad2


def compose(est: Estimates, T_base_lidar: np.ndarray | None, T_ref: np.ndarray | None,
            wheel_topic: str | None = None) -> Calibration:
    """The calibration the estimates give (only what was estimated; sigmas about/along the base axes)."""
    out: dict = {}
    T_li = T_lidar_imu_of(est, T_ref)
    if T_li is not None and T_base_lidar is not None:
        Rbl = T_base_lidar[:3, :3]
        out["T_base_lidar"] = _rows(T_base_lidar)
        out["T_base_imu"] = _rows(T_base_lidar @ T_li)
        out["T_base_imu_rotation_sigma_rad"] = _sig(Rbl @ rotation_cov_lidar(est) @ Rbl.T, ROTATION_SIGMA_CAP_RAD)
        if est.lever is not None:
            cov_t = est.lever.covariance_m2.copy()
            out["T_base_imu_translation_sigma_m"] = _sig(Rbl @ cov_t @ Rbl.T, MAX_LEVER_ARM_M)
    if est.offset is not None and not est.offset_assumed:  # assumed: zero used, nothing measured or given
        out["imu_time_offset_s"] = round(float(est.offset.imu_time_offset_s), 7)
        if np.isfinite(est.offset.sigma_s):  # NaN: kept from --calib, the motion could not time the IMU
            out["imu_time_offset_sigma_s"] = float(f"{est.offset.sigma_s:.3g}")
    if est.static is not None:
        out["gyro_bias_radps"] = _list(est.static.gyro_bias_radps)
        out["gyro_bias_sigma_radps"] = _list(est.static.gyro_bias_sigma_radps, 3)
    elif est.rotation is not None:
        out["gyro_bias_radps"] = _list(est.rotation.gyro_bias_radps)
        out["gyro_bias_sigma_radps"] = _list(est.rotation.gyro_bias_sigma_radps, 3)
    if est.lever is not None and (est.lever.accel_bias_sigma_mps2 <= MAX_ACCEL_BIAS_SIGMA_MPS2).all():
        out["accel_bias_mps2"] = _list(est.lever.accel_bias_mps2)
        out["accel_bias_sigma_mps2"] = _list(est.lever.accel_bias_sigma_mps2, 3)
    elif est.static is not None:
        out["accel_bias_mps2"] = _list(est.static.accel_bias_mps2)
        sig = est.static.accel_bias_along_gravity_sigma_mps2
        out["accel_bias_sigma_mps2"] = _list(np.abs(est.static.up_imu) * sig, 3)
    noise = _noise(est)
    if noise is not None:
        out["imu_noise"] = noise
    if est.wheel is not None:
        w = est.wheel
        out["wheel"] = WheelCalibration(
            topic=wheel_topic, speed_scale=round(w.speed_scale, 6), speed_scale_sigma=float(f"{w.speed_scale_sigma:.3g}"),
            yaw_rate_scale=round(w.yaw_rate_scale, 6), yaw_rate_scale_sigma=float(f"{w.yaw_rate_scale_sigma:.3g}"),
            radius_m=_opt(w.radius_m), radius_sigma_m=_opt(w.radius_sigma_m, 3), baseline_m=_opt(w.baseline_m),
            baseline_sigma_m=_opt(w.baseline_sigma_m, 3))
    return Calibration.model_validate(out)


def _noise(est: Estimates) -> ImuNoiseCalibration | None:
    if est.allan is not None:
        g, a = est.allan.gyro, est.allan.accel
        return ImuNoiseCalibration(
            source=f"Allan variance of {est.allan.duration_s:.0f} s", gyro_noise_radps=_g(g.noise_density_mean),
            accel_noise_mps2=_g(a.noise_density_mean), gyro_bias_walk=_g(g.random_walk_mean),
            accel_bias_walk=_g(a.random_walk_mean), gyro_bias_instability_radps=_g(np.nanmean(g.bias_instability)),
            accel_bias_instability_mps2=_g(np.nanmean(a.bias_instability)))
    if est.static is not None:
        s = est.static
        return ImuNoiseCalibration(
            source=f"still stretch of {(s.end_ns - s.start_ns) / 1e9:.1f} s (white noise only)",
            gyro_noise_radps=_g(np.mean(s.gyro_noise_density)), accel_noise_mps2=_g(np.mean(s.accel_noise_density)))
    return None


def table(cal: Calibration, ref: Calibration | None, ref_name: str | None) -> list[dict]:
    """Rows {quantity, unit, value, sigma, diff}: diff = estimate - reference (None where there is none)."""
    rows: list[dict] = []

    def add(q, unit, value, sigma=None, diff=None):
        rows.append({"quantity": q, "unit": unit, "value": value, "sigma": sigma, "diff": diff})

    if cal.T_base_imu is not None:
        T, Tr = cal.matrix("T_base_imu"), (ref.matrix("T_base_imu") if ref is not None else None)
        rpy, sig = np.degrees(_rpy(T[:3, :3])), np.degrees(cal.T_base_imu_rotation_sigma_rad)
        d_rot = None if Tr is None else np.degrees(so3_log(T[:3, :3] @ Tr[:3, :3].T))
        for i, name in enumerate(("roll (x)", "pitch (y)", "yaw (z)")):
            add(f"T_base_imu rotation {name}", "deg", rpy[i], sig[i], None if d_rot is None else d_rot[i])
        sig_t = cal.T_base_imu_translation_sigma_m
        for i, a in enumerate(AXES):
            add(f"T_base_imu translation {a}", "cm", 100 * T[i, 3], None if sig_t is None else 100 * sig_t[i],
                None if Tr is None else 100 * (T[i, 3] - Tr[i, 3]))
    if "imu_time_offset_s" in cal.model_fields_set:
        given = ref is not None and ref_name == "--calib"  # /tf_static has no clock offset
        sig = cal.imu_time_offset_sigma_s
        add("imu_time_offset_s", "ms", 1e3 * cal.imu_time_offset_s, None if sig is None else 1e3 * sig,
            1e3 * (cal.imu_time_offset_s - ref.imu_time_offset_s) if given else None)
    for name, unit in (("gyro_bias_radps", "rad/s"), ("accel_bias_mps2", "m/s^2")):
        v, s = getattr(cal, name), getattr(cal, name.replace("_radps", "_sigma_radps").replace("_mps2", "_sigma_mps2"))
        r = getattr(ref, name) if ref is not None else None
        if v is not None:
            for i, a in enumerate(AXES):
                add(f"{name.split('_')[0]} bias {a}", unit, v[i], s[i] if s else None, None if r is None else v[i] - r[i])
    if cal.imu_noise is not None:
        n = cal.imu_noise
        for f, unit in (("gyro_noise_radps", "rad/s/sqrt(Hz)"), ("accel_noise_mps2", "m/s^2/sqrt(Hz)"),
                        ("gyro_bias_walk", "rad/s^2/sqrt(Hz)"), ("accel_bias_walk", "m/s^3/sqrt(Hz)")):
            if getattr(n, f) is not None:
                add(f"imu_noise.{f}", unit, getattr(n, f))
    if cal.wheel is not None:
        w = cal.wheel
        add("wheel speed scale", "", w.speed_scale, w.speed_scale_sigma)
        add("wheel yaw-rate scale", "", w.yaw_rate_scale, w.yaw_rate_scale_sigma)
        if w.radius_m is not None:
            add("wheel radius", "cm", 100 * w.radius_m, 100 * w.radius_sigma_m)
        if w.baseline_m is not None:
            add("wheel baseline", "cm", 100 * w.baseline_m, 100 * w.baseline_sigma_m)
    for r in rows:
        for k in ("value", "sigma", "diff"):
            if r[k] is not None:
                r[k] = float(r[k])
    return rows


def format_table(rows: list[dict], ref_name: str | None) -> list[str]:
    head = ("quantity", "value", "1-sigma", f"minus {ref_name}" if ref_name else "difference", "unit")
    body = [(r["quantity"], _num(r["value"]), _num(r["sigma"]), _num(r["diff"], signed=True), r["unit"]) for r in rows]
    widths = [max(len(x[i]) for x in [head, *body]) for i in range(5)]
    lines = ["  ".join(c.ljust(w) if i in (0, 4) else c.rjust(w) for i, (c, w) in enumerate(zip(x, widths))).rstrip()
             for x in [head, *body]]
    return lines


def reference_T_lidar_imu(ref: Calibration | None, T_base_lidar: np.ndarray | None) -> np.ndarray | None:
    if ref is None or ref.T_base_imu is None or T_base_lidar is None:
        return None
    return inv_pose(T_base_lidar) @ ref.matrix("T_base_imu")


def _rpy(R: np.ndarray) -> np.ndarray:
    """(roll, pitch, yaw) of R = Rz(yaw) Ry(pitch) Rx(roll)."""
    return np.array([np.arctan2(R[2, 1], R[2, 2]), -np.arcsin(np.clip(R[2, 0], -1, 1)), np.arctan2(R[1, 0], R[0, 0])])


def _num(v, signed=False) -> str:
    if v is None:
        return "-"
    a = abs(v)
    text = f"{v:+.3g}" if signed else f"{v:.3g}"
    if 1e-3 <= a < 1e4:
        text = f"{v:+.4f}" if signed else f"{v:.4f}"
        text = text.rstrip("0").rstrip(".") if "." in text else text
    return text


def _rows(T: np.ndarray) -> list[list[float]]:
    T = np.asarray(T, float).copy()
    T[3] = (0, 0, 0, 1)
    return [[round(float(x), 9) for x in r] for r in T]


def _sig(cov: np.ndarray, cap: float) -> list[float]:
    """1-sigmas of ``cov``, at most ``cap`` (the calibration file's bound: a wider one says nothing more)."""
    return [float(f"{x:.3g}") for x in np.minimum(np.sqrt(np.clip(np.diag(cov), 0, None)), cap)]


def _list(v, digits: int | None = None) -> list[float]:
    return [float(f"{x:.{digits}g}") if digits else round(float(x), 9) for x in v]


def _g(x) -> float | None:
    return None if x is None or not np.isfinite(x) else float(f"{float(x):.4g}")


def _opt(x, digits: int = 6) -> float | None:
    return None if x is None else (float(f"{x:.{digits}g}") if digits == 3 else round(float(x), digits))
