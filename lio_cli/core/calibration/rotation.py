"""LiDAR-IMU rotation by hand-eye on rotation increments.

Over windows of ``window_s`` (all start scans, so windows overlap) the LiDAR trajectory's rotation increments
``phi_lidar`` and the gyro's ``phi_imu`` (integrated over the same LiDAR-clock interval, shifted by the time
offset) obey ``phi_lidar = R_lidar_imu (phi_imu - b dt)``. Kabsch gives a start; Gauss-Newton on the
rotation and the gyro bias correction ``b`` (the gyro re-integrated with the bias each round, so long windows
stay exact) gives the estimate, with an optional prior (e.g. /tf_static) that only matters along directions
the motion does not show. Longer windows hold more rotation against the same per-pose noise, unless the
motion turns back within them (a handheld sweep): the length is chosen per trajectory (``WINDOWS_S``).

The trajectory is a registration's, and a registration need not turn as the sensor did: LiDAR-only odometry of
a car follows only part of its slow roll and pitch sways, and roll that comes with the turns would read as a
tilted mounting. So a symmetric gain ``S`` (``phi_lidar = (I + S) R (phi_imu - b dt)``; a rotation has no
symmetric part) is fitted too, and kept when it is clearly there and the motion can tell it from the mounting.

Errors are ``R_est = exp(e) R_true`` with ``e`` in the LiDAR frame: ``sigma_rad`` is the 1-sigma of e about
the LiDAR's x, y, z axes. Pass the trajectory of the base instead and everything reads base for LiDAR.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import NamedTuple

import numpy as np

from ...errors import InputError
from ...geometry import skew, so3_exp, so3_log
from .common import (NS_PER_S, CalibrationResult, check_imu, check_overlap, check_trajectory, outliers_3d,
                     sandwich_covariance)
from .excitation import axis_name, dominant_rotation_axis, floored, per_axis, turned_mostly_about, weak_directions
from .handeye import align, imu_increments, interval_pairs, keep_finite_increments, lidar_increments
from .signals import GyroOrientation

# window lengths to choose from (``window_s`` None): the one whose windows turn most for their length (mean squared
# angle over the length); a handheld sweep turns back within a second, a vehicle turns more in longer windows
WINDOWS_S = (0.5, 1.0)
MIN_WINDOWS = 40  # a shorter length only when the trajectory spans this many: fewer are too few for their covariance
REG_SIGMA_RAD = 1.0  # regularisation of directions nothing observes (keeps the normal matrix invertible)
REG_SIGMA_BIAS_RADPS = 1.0
OUTLIER_FLOOR_RAD = 1e-4  # residual sigma below which nothing is an outlier
REG_GAIN = 1.0
# the registration's gain: it may report a rotation other than the one the sensor made, e.g. LiDAR-only odometry
# of a vehicle follows a fraction of its slow roll and pitch sways (the map it matches was built on poses with
# the same error); modelled (phi_lidar = (I + S) R phi_imu, S symmetric: a rotation has no symmetric part) when
# an entry of S departs from zero by more than this and by GAIN_SIGMAS of its 1-sigma
GAIN_TOL = 0.05
GAIN_SIGMAS = 4.0
GAIN_ENTRIES = (np.array([0, 1, 2, 0, 0, 1]), np.array([0, 1, 2, 1, 2, 2]))
_GAIN_BASIS = np.zeros((6, 3, 3))
_GAIN_BASIS[np.arange(6), GAIN_ENTRIES[0], GAIN_ENTRIES[1]] = 1.0
_GAIN_BASIS[np.arange(6), GAIN_ENTRIES[1], GAIN_ENTRIES[0]] = 1.0


@dataclass(frozen=True, eq=False)
class RotationCalib(CalibrationResult):
    R_lidar_imu: np.ndarray  # (3,3): maps IMU vectors into the LiDAR frame
    sigma_rad: np.ndarray  # (3,) about the LiDAR x, y, z axes
    covariance_rad2: np.ndarray  # (3,3)
    observable: np.ndarray  # (3,) bool per LiDAR axis: sigma below the threshold
    gyro_bias_radps: np.ndarray  # (3,) IMU frame, fitted alongside
    gyro_bias_sigma_radps: np.ndarray
    windows: int
    rms_residual_rad: float
    notes: tuple[str, ...]
    registration_gain: np.ndarray  # (3,3) symmetric S: the trajectory turns by (I + S) R phi_imu (zero: not modelled)
    fit_covariance_rad2: np.ndarray  # (3,3) the fit's own, before any floor (what a later fit may lean on)


def estimate_rotation(lidar_stamps_ns: np.ndarray, T_world_lidar: np.ndarray, imu_stamps_ns: np.ndarray,
                      gyro_radps: np.ndarray, *, imu_time_offset_s: float = 0.0,
                      gyro_bias_radps: np.ndarray | None = None, window_s: float | None = None,
                      R_lidar_imu_prior: np.ndarray | None = None, prior_sigma_rad: float = np.radians(10.0),
                      max_sigma_rad: float = np.radians(1.0), frame: str = "LiDAR",
                      sigma_floor_rad: np.ndarray | None = None, refuse_sigma_rad: float | None = None) -> RotationCalib:
    """R_lidar_imu from a LiDAR odometry trajectory and the gyro (IMU stamps + ``imu_time_offset_s`` = LiDAR
    clock). Axes whose 1-sigma exceeds ``max_sigma_rad`` are reported unobservable (with the motion that would
    show them); when every axis exceeds ``refuse_sigma_rad`` (default ``max_sigma_rad``), InputError: a first
    estimate that only seeds sharper passes may be vaguer. ``sigma_floor_rad``: per-axis 1-sigmas not to report
    below (a trajectory whose poses' errors are shared, which its residuals understate)."""
    ls, poses = check_trajectory(lidar_stamps_ns, T_world_lidar)
    istamps, gyro, _ = check_imu(imu_stamps_ns, gyro_radps)
    check_overlap(istamps, ls, imu_time_offset_s)
    bias = np.zeros(3) if gyro_bias_radps is None else np.asarray(gyro_bias_radps, np.float64).copy()
    span_s = (ls[-1] - ls[0]) / NS_PER_S
    lengths = [w for w in WINDOWS_S if w == max(WINDOWS_S) or span_s >= MIN_WINDOWS * w] if window_s is None else [window_s]
    dt_ns = float(np.median(np.diff(ls)))  # a window is whole scans: its real length is span * dt_ns
    choices = [_windows(ls, poses, istamps, imu_time_offset_s, w, dt_ns) for w in lengths]
    window_s, span, ia, ib, phi_l = max(choices, key=lambda c: (len(c[4]) >= 10, phi_turn(c[4]) / c[1], -c[1]))
    if len(ia) < 10:
        raise InputError(f"{frame}-IMU rotation: only {len(ia)} windows of {window_s:g} s overlap the IMU data (need 10)")
    ta, tb = ls[ia], ls[ib]
    dt = (tb - ta) / NS_PER_S
    notes: list[str] = []

    R = None
    keep = np.ones(len(ia), bool)
    for rnd in range(4):  # re-integrate the gyro with the bias found so far; after the first, drop outliers once
        phi_i = imu_increments(GyroOrientation(istamps, gyro, bias), ta[keep], tb[keep], imu_time_offset_s)
        if R is None:
            R, _, r0 = align(phi_l, phi_i, dt)
            noise = max(float(np.sqrt((r0 * r0).mean())), 1e-9)  # per-component residual: whitens the problem
            if R_lidar_imu_prior is not None:
                R = np.asarray(R_lidar_imu_prior, np.float64)
        fit = _gauss_newton(R, phi_l[keep], phi_i, dt[keep], noise, R_lidar_imu_prior, prior_sigma_rad)
        R, bias = fit.R, bias + fit.b
        bad = outliers_3d(noise * np.linalg.norm(fit.r, axis=1), OUTLIER_FLOOR_RAD)  # r is whitened
        if rnd == 0 and bad.any():
            keep[np.flatnonzero(keep)[bad]] = False
            n = int(bad.sum())
            notes.append(f"{n} window{'s' * (n != 1)} left out: {'their' if n != 1 else 'its'} rotation disagrees "
                         "with the gyro's (bad registrations?)")
    cov = fit.covariance(span)
    fit_cov = cov[:3, :3].copy()
    cov[:3, :3] = floored(cov[:3, :3], sigma_floor_rad)
    gain = _gauss_newton(R, phi_l[keep], phi_i, dt[keep], noise, R_lidar_imu_prior, prior_sigma_rad, gain=True)
    cov_g = gain.covariance(span)
    cov_g[:3, :3] = floored(cov_g[:3, :3], sigma_floor_rad)
    S = gain.S[GAIN_ENTRIES]
    z = np.abs(S) / np.sqrt(np.diag(cov_g)[6:])
    # ...unless the motion cannot tell the gain from the mounting (a 2D scanner reports no roll or pitch at all,
    # and a platform that only turns about the vertical cannot show how the registration would follow them)
    sigma, observable = per_axis(cov[:3, :3], max_sigma_rad)
    identifiable = (per_axis(cov_g[:3, :3], max_sigma_rad)[1] >= observable).all()
    modelled = bool(identifiable and ((np.abs(S) > GAIN_TOL) & (z > GAIN_SIGMAS)).any())
    if modelled:
        fit_cov = gain.covariance(span)[:3, :3]
        R, bias, cov, fit = gain.R, bias + gain.b, cov_g, gain
        sigma, observable = per_axis(cov[:3, :3], max_sigma_rad)
        w = np.linalg.eigvalsh(gain.S)
        notes.append(f"the {frame} trajectory turns by {100 * (1 + w[0]):.0f}% to {100 * (1 + w[-1]):.0f}% of the "
                     f"gyro's rotation, depending on the axis (LiDAR-only registration following a fraction of slow "
                     f"roll and pitch sways?): modelled, the mounting is estimated from the rest")
    refuse = max_sigma_rad if refuse_sigma_rad is None else max(refuse_sigma_rad, max_sigma_rad)
    _explain(cov[:3, :3], phi_l[keep], max_sigma_rad, frame, notes, R_lidar_imu_prior is not None, refuse)
    return RotationCalib(R, sigma, cov[:3, :3], observable, bias, np.sqrt(np.diag(cov[3:6, 3:6])), int(keep.sum()),
                         float(noise * np.sqrt((fit.r * fit.r).mean())), tuple(notes),
                         gain.S if modelled else np.zeros((3, 3)), fit_cov)


def _windows(ls: np.ndarray, poses: np.ndarray, istamps: np.ndarray, offset_s: float, window_s: float,
             dt_ns: float) -> tuple:
    """(window_s, span in scans, start and end scans, LiDAR rotation increments) of the windows of ``window_s``
    (whole scans ``dt_ns`` apart) inside the IMU."""
    span = max(1, int(round(window_s * NS_PER_S / dt_ns)))
    ia, ib = interval_pairs(ls, span)
    off_ns = int(round(offset_s * NS_PER_S))
    inside = (ls[ia] >= istamps[0] + off_ns) & (ls[ib] <= istamps[-1] + off_ns)
    ia, ib = ia[inside], ib[inside]
    phi_l = lidar_increments(poses, ia, ib)
    ok = keep_finite_increments(phi_l)
    return window_s, span, ia[ok], ib[ok], phi_l[ok]


def phi_turn(phi: np.ndarray) -> float:
    """Mean squared angle of rotation increments (0 for none)."""
    return float(np.mean(np.einsum("ni,ni->n", phi, phi))) if len(phi) else 0.0


class _Fit(NamedTuple):
    """What ``_gauss_newton`` ends at: the mounting, bias and gain, the whitened residuals and Jacobian, the
    normal matrix with the prior, and the prior's information."""

    R: np.ndarray
    b: np.ndarray
    S: np.ndarray
    r: np.ndarray
    H: np.ndarray
    J: np.ndarray
    prior_info: np.ndarray

    def covariance(self, lag: int) -> np.ndarray:
        return sandwich_covariance(self.H, np.einsum("nji,nj->ni", self.J, self.r), lag=lag,
                                   prior_info=self.prior_info)


def _gauss_newton(R: np.ndarray, phi_l: np.ndarray, phi_i: np.ndarray, dt: np.ndarray, noise: float,
                  R_prior: np.ndarray | None, prior_sigma_rad: float, gain: bool = False, iterations: int = 4) -> _Fit:
    """Minimise sum |phi_l - (I + S) R (phi_i - b dt)|^2 / noise^2 (+ prior on R) over R = exp(d) R, b and, with
    ``gain``, the symmetric S (six entries, ``GAIN_ENTRIES``; else S = 0)."""
    b, S = np.zeros(3), np.zeros((3, 3))
    Rp = R if R_prior is None else np.asarray(R_prior, np.float64)
    n_par = 12 if gain else 6
    prior_info = np.zeros((n_par, n_par))
    prior_info[:3, :3] = np.eye(3) / (prior_sigma_rad if R_prior is not None else REG_SIGMA_RAD) ** 2
    prior_info[3:6, 3:6] = np.eye(3) / REG_SIGMA_BIAS_RADPS**2
    prior_info[6:, 6:] = np.eye(n_par - 6) / REG_GAIN**2
    for it in range(iterations + 1):
        u = (phi_i - b * dt[:, None]) @ R.T
        A = np.eye(3) + S
        r = (phi_l - u @ A.T) / noise
        J = np.concatenate([A @ skew(u), (A @ R)[None] * dt[:, None, None]], axis=2) / noise
        if gain:
            J = np.concatenate([J, -np.einsum("mjk,nk->njm", _GAIN_BASIS, u) / noise], axis=2)
        H = np.einsum("nji,njk->ik", J, J) + prior_info
        if it == iterations:
            return _Fit(R, b, S, r, H, J, prior_info)
        g = np.einsum("nji,nj->i", J, r)
        g[:3] += prior_info[0, 0] * so3_log(R @ Rp.T)
        if gain:
            g[6:] += prior_info[6, 6] * S[GAIN_ENTRIES]
        step = -np.linalg.solve(H, g)
        R = so3_exp(step[:3]) @ R
        b = b + step[3:6]
        if gain:
            S = S + np.einsum("m,mjk->jk", step[6:], _GAIN_BASIS)
    raise AssertionError("unreachable")


def _explain(cov: np.ndarray, phi_l: np.ndarray, max_sigma_rad: float, frame: str, notes: list[str],
             has_prior: bool, refuse_sigma_rad: float) -> None:
    weak = weak_directions(cov, max_sigma_rad)
    axis, share = dominant_rotation_axis(phi_l)
    if len(weak_directions(cov, refuse_sigma_rad)) == 3:
        raise InputError(f"too little rotation to estimate the {frame}-IMU rotation (1-sigma {np.degrees(weak[-1][1]):.1f} "
                         f"deg or worse on every axis): rotate the sensor about all three axes (yaw, pitch and roll "
                         f"sweeps of +-30 deg)")
    kept = "stays at the prior" if has_prior else "is arbitrary"
    for v, s in weak:
        about = axis_name(v, frame)
        if turned_mostly_about(v, axis, share):
            why = (f"the platform turned only about that axis ({100 * share:.0f}% of its rotation), as a ground "
                   f"vehicle turning about the vertical does")
        else:
            why = "the motion barely turned about the other axes"
        notes.append(f"the mounting's rotation about {about} is not observable from rotations (1-sigma "
                     f"{np.degrees(s):.1f} deg; it {kept}): {why}; tilt or roll the platform too (a vehicle: drive over "
                     f"ramps or bumps), or take that angle from accelerations (lever_arm refines it) or the drawing")
