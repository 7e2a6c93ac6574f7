"""The ground's grade under a ground robot the planar estimator tracks, from the IMU's slow pitch: over hills the
planar output's height climbs it (``heave.lift``) and its pitch keeps it (``level.lift``); on flat ground both stay
level.

The grade is the up direction's pitch (``level.up_directions``) below the heave's crossover, less its mean along
the distance driven: the IMU's mount and its accelerometer's bias are one to the data with a grade held over the
whole log, so a drive that climbs on the whole reads its climb as a tilt. The body's own pitch on its suspension
leaks into that slow part (a sway's start, the filter's ends), and an IMU yawed against its calibration feels the
turns' centripetal acceleration on its forward axis as a slow pitch: the grade is followed only where its climb,
with the slow pitch's share that follows the lateral acceleration taken out, is ``SIGNIFICANCE`` times what the
faster pitch alone would climb, and where the wheels' scale the accelerometer fitted does not say the IMU's
forward axis is another (``forward_axis_checked``). The grade followed keeps that share (a true grade may happen
to follow the turns). Where the wheel speed is unknown (a hole in its messages) and across IMU gaps the grade is
zero: the accelerometer's up there is not the ground's."""

from __future__ import annotations

import numpy as np

from . import heave
from .level import slow_part
from .timeline import Prepared

SIGNIFICANCE = 2.0  # a grade's climb over the sway's that makes the height follow it
# the wheels' fitted scale further from 1 than this (and than SCALE_Z of its sigmas) says the IMU's forward axis
# may not be the base's: groovy.bag with an identity extrinsic fits 0.83 +- 0.02
MAX_SCALE_OFF = 0.1
SCALE_Z = 3.0
WHEEL_HOLE_S = 0.5  # wheel messages further apart than this (and 5 periods) leave the speed unknown between them


def estimate(prep: Prepared, up_imu: np.ndarray, gravity_mps2: float = 9.81) -> tuple[np.ndarray | None, dict]:
    """(N,) the grade as a pitch (rad, Z-Y-X) at the IMU stamps where the data show one, else None; and what
    decided (the module docstring)."""
    stamps = prep.imu.stamps_ns
    ti = (stamps - stamps[0]) * 1e-9
    period = float(np.median(np.diff(ti)))
    dt = np.diff(ti, prepend=ti[0])
    gap_ns = prep.imu_gap_ns if prep.imu_gap_ns > 0 else 5.0 * period * 1e9
    dt[1:][np.diff(stamps) > gap_ns] = 0.0
    known = (dt > 0) & ~_wheel_holes(prep)
    pitch = -np.arcsin(np.clip(up_imu[:, 0], -1.0, 1.0))
    slow = slow_part(ti, pitch, heave.CROSSOVER_HZ)
    v = np.interp(stamps, prep.wheel.stamps_ns, np.nan_to_num(prep.wheel.velocity_mps[:, 0]))
    step = np.where(known, v * dt, 0.0)
    lateral = slow_part(ti, v * prep.imu_w_b[:, 2] / gravity_mps2, heave.CROSSOVER_HZ)
    leak = _leak(slow, lateral, np.abs(step))
    g, turns_out = _about_mean(slow, step, known), _about_mean(slow - leak * lateral, step, known)
    climb, rest = np.cumsum(-step * np.sin(g)), np.cumsum(-step * np.sin(turns_out))
    sway = np.cumsum(-step * np.sin(pitch - slow))
    info = {"climb_rms_m": round(float(np.std(climb)), 4), "lateral_leak": round(leak, 4),
            "climb_beside_turns_rms_m": round(float(np.std(rest)), 4),
            "sway_climb_rms_m": round(float(np.std(sway)), 4), "imu_forward_checked": forward_axis_checked(prep)}
    info["followed"] = bool(info["imu_forward_checked"]
                            and info["climb_beside_turns_rms_m"] > SIGNIFICANCE * info["sway_climb_rms_m"])
    return (g if info["followed"] else None), info


def _leak(slow: np.ndarray, lateral: np.ndarray, weight: np.ndarray) -> float:
    """The least-squares share of the slow lateral acceleration (in g) in the slow pitch, weighted by distance."""
    w = weight / max(float(weight.sum()), 1e-12)
    x, y = lateral - float(w @ lateral), slow - float(w @ slow)
    den = float(w @ (x * x))
    return float(w @ (x * y)) / den if den > 1e-12 else 0.0


def _about_mean(pitch: np.ndarray, step: np.ndarray, known: np.ndarray) -> np.ndarray:
    """``pitch`` less its mean along the distance (``step``, m per sample), zero where the speed is not known."""
    w = np.abs(step)
    ds = float(w.sum())
    return np.where(known, pitch - (float(w @ pitch) / ds if ds > 0 else 0.0), 0.0)


def _wheel_holes(prep: Prepared) -> np.ndarray:
    """(N,) the IMU samples between two wheel messages further apart than ``WHEEL_HOLE_S`` and 5 periods."""
    tw = prep.wheel.stamps_ns
    if len(tw) < 2:
        return np.ones(len(prep.imu.stamps_ns), bool)
    d = np.diff(tw)
    far = np.flatnonzero(d > max(WHEEL_HOLE_S * 1e9, 5.0 * float(np.median(d))))
    k = np.searchsorted(tw, prep.imu.stamps_ns, side="right") - 1
    return np.isin(k, far) | (prep.imu.stamps_ns < tw[0]) | (prep.imu.stamps_ns > tw[-1])


def forward_axis_checked(prep: Prepared) -> bool:
    """Whether the IMU's pitch can be the ground's: the accelerometer's forward acceleration fitted the wheels'
    (``wheel_slip``) at a scale within ``MAX_SCALE_OFF`` of 1 or ``SCALE_Z`` of its sigmas. Far off 1, the IMU's
    forward axis may not be the base's, whatever the wheels (an IMU yawed by a few degrees fits near 1: its lateral
    leak is ``estimate``'s)."""
    wc = prep.wheel_check or {}
    scale, sigma = wc.get("scale"), wc.get("scale_sigma")
    return scale is not None and sigma is not None and abs(scale - 1.0) <= max(MAX_SCALE_OFF, SCALE_Z * sigma)
