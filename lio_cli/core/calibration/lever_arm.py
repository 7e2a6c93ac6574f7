"""LiDAR-IMU translation (lever arm) from accelerations, refining the rotation on the way.

No differentiation of noisy positions: over three scans a < b < c the second divided difference of a position
is exactly the hat-kernel average of its acceleration (peak at b, zero at a and c). The IMU's position is
``p_lidar + R_world_lidar t`` (``t`` the lever arm, in the LiDAR frame), its acceleration ``R_world_imu f + g``
(``f`` the specific force minus its bias), so for every window

    DD(p_lidar) + DD(R_world_lidar) t = R_world_lidar(b) R_lidar_imu (A - C b_a) + g_world

with ``A``, ``C`` the hat averages of ``G(b)^T G(s) f(s)`` and ``G(b)^T G(s)`` (``G`` the gyro's orientation,
so the IMU's rotation within the window comes from the gyro, not from interpolated poses). Unknowns: the lever
arm, the accelerometer bias, gravity in the trajectory's world frame (LiDAR odometry's world is its first
scan, not levelled) and, when the rotation's covariance is given, a correction to the rotation (its prior):
accelerations see the mounting's yaw that a vehicle turning about the vertical hides from the gyro.

Windows are consecutive scan triples. Their position noise is large (a second difference of centimetre noise
over 0.1 s) but shared: neighbouring windows use the same poses, so it cancels over longer spans, and
generalised least squares with that covariance (per-pose position noise plus a white part for the IMU side,
both at their maximum-likelihood levels) recovers the information. Outlying windows are left out once.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.linalg import cholesky_banded, solve_banded
from scipy.optimize import minimize

from ...errors import InputError
from ...geometry import skew, so3_exp, so3_log
from .common import (NS_PER_S, CalibrationResult, check_imu, check_overlap, check_trajectory, outliers_3d,
                     sandwich_covariance)
from .excitation import axis_name, dominant_rotation_axis, floored, per_axis, turned_mostly_about, weak_directions
from .handeye import interval_pairs, lidar_increments
from .signals import GyroOrientation, PiecewiseLinear, second_divided_difference

NOISE_ROUNDS = 3
OUTLIER_FLOOR_MPS2 = 1e-3  # residual sigma below which nothing is an outlier
SEARCH_SIGMA_RAD = np.radians(1.0)  # a prior this vague about an axis (not observable): the angle about it is searched...
SEARCH_STEP_DEG = 5.0  # ...on this grid (the Gauss-Newton iterations take it from there)
CORRELATION_S = 1.0  # windows this far apart may share slow registration errors (the sandwich covariance's lag)


@dataclass(frozen=True, eq=False)
class LeverArmCalib(CalibrationResult):
    t_lidar_imu_m: np.ndarray  # (3,) the IMU origin in the LiDAR frame (translation of T_lidar_imu)
    sigma_m: np.ndarray  # (3,) along the LiDAR x, y, z axes
    covariance_m2: np.ndarray  # (3,3)
    observable: np.ndarray  # (3,) bool per LiDAR axis
    R_lidar_imu: np.ndarray  # (3,3): refined when a rotation covariance was given, else the one given
    rotation_sigma_rad: np.ndarray  # (3,) about the LiDAR axes (NaN when not refined)
    rotation_covariance_rad2: np.ndarray  # (3,3)
    accel_bias_mps2: np.ndarray  # (3,) IMU frame
    accel_bias_sigma_mps2: np.ndarray
    gravity_world_mps2: np.ndarray  # (3,) in the trajectory's world frame
    windows: int
    rms_residual_mps2: float  # of the windows' accelerations, dominated by the trajectory's position noise
    notes: tuple[str, ...]


def estimate_lever_arm(lidar_stamps_ns: np.ndarray, T_world_lidar: np.ndarray, imu_stamps_ns: np.ndarray,
                       gyro_radps: np.ndarray, accel_mps2: np.ndarray, *, R_lidar_imu: np.ndarray,
                       rotation_covariance_rad2: np.ndarray | None = None, imu_time_offset_s: float = 0.0,
                       gyro_bias_radps: np.ndarray | None = None,
                       t_prior_m: np.ndarray | None = None, prior_sigma_m: float = 1.0,
                       max_sigma_m: float = 0.05, frame: str = "LiDAR", sigma_floor_m: np.ndarray | None = None,
                       rotation_sigma_floor_rad: np.ndarray | None = None, span: int = 1) -> LeverArmCalib:
    """Lever arm (and, with ``rotation_covariance_rad2``, a refined rotation) from a LiDAR odometry trajectory
    and the IMU (stamps + ``imu_time_offset_s`` = LiDAR clock; ``gyro_bias_radps`` as estimate_rotation found
    it). ``t_prior_m`` (default zero, 1-sigma ``prior_sigma_m``) weakly holds directions the motion does not
    show; those (1-sigma above ``max_sigma_m``) are flagged and named in the notes (keep a measured value for
    them), and InputError when none is shown. ``sigma_floor_m``, ``rotation_sigma_floor_rad``: per-axis 1-sigmas
    of the lever arm and the refined rotation not to report below (a trajectory whose poses' errors are shared,
    which its residuals understate)."""
    ls, poses = check_trajectory(lidar_stamps_ns, T_world_lidar)
    istamps, gyro, accel = check_imu(imu_stamps_ns, gyro_radps, accel_mps2)
    check_overlap(istamps, ls, imu_time_offset_s)
    R0 = np.asarray(R_lidar_imu, np.float64)
    refine = rotation_covariance_rad2 is not None
    ia, ic = interval_pairs(ls, 2 * span)
    off_ns = int(round(imu_time_offset_s * NS_PER_S))
    inside = (ls[ia] >= istamps[0] + off_ns) & (ls[ic] <= istamps[-1] + off_ns)
    ia, ic = ia[inside], ic[inside]
    ib = ia + span
    if len(ia) < 20:
        raise InputError(f"{frame}-IMU lever arm: only {len(ia)} scan triples overlap the IMU data (need 20)")
    notes: list[str] = []
    w = _Windows(ls, poses, istamps, gyro, accel, gyro_bias_radps, imu_time_offset_s, ia, ib, ic)

    prior_t = np.zeros(3) if t_prior_m is None else np.asarray(t_prior_m, np.float64)
    keep = np.ones(len(ia), bool)
    for attempt in range(2):
        x, R, H, info, scores = _solve(w, keep, R0, refine, rotation_covariance_rad2, prior_t, prior_sigma_m)
        raw, _ = _rows(w, keep, x, R, refine)  # outliers judged unwhitened: whitening spreads one bad pose
        bad = outliers_3d(np.linalg.norm(raw, axis=1), OUTLIER_FLOOR_MPS2)
        if attempt == 1 or not bad.any():
            break
        keep[np.flatnonzero(keep)[bad]] = False
        n = int(bad.sum())
        verb = "their accelerations disagree" if n != 1 else "its acceleration disagrees"
        notes.append(f"{n} window{'s' * (n != 1)} left out: {verb} with the IMU's (bad registrations?)")
    cov = _honest_covariance(H, info, scores, ls[ic[keep]] - ls[ia[keep]])
    cov[:3, :3] = floored(cov[:3, :3], sigma_floor_m)
    if refine:
        cov[9:12, 9:12] = floored(cov[9:12, 9:12], rotation_sigma_floor_rad)
    sigma, observable = per_axis(cov[:3, :3], max_sigma_m)
    cov_t = cov[:3, :3]
    _explain(cov_t, lidar_increments(poses, ia[keep], ic[keep]), max_sigma_m, frame, notes, refuse=not refine)
    rcov = cov[9:12, 9:12] if refine else np.full((3, 3), np.nan)
    return LeverArmCalib(
        t_lidar_imu_m=x[:3], sigma_m=sigma, covariance_m2=cov_t, observable=observable, R_lidar_imu=R,
        rotation_sigma_rad=np.sqrt(np.diag(rcov)) if refine else np.full(3, np.nan), rotation_covariance_rad2=rcov,
        accel_bias_mps2=x[3:6], accel_bias_sigma_mps2=np.sqrt(np.diag(cov[3:6, 3:6])), gravity_world_mps2=x[6:9],
        windows=int(keep.sum()), rms_residual_mps2=float(np.sqrt((raw * raw).mean())), notes=tuple(notes))


class _Windows:
    """Per scan triple: DD of LiDAR position and rotation, the LiDAR rotation at b, the IMU's hat averages, and
    the poses and weights of the DD (for the noise the triples share)."""

    def __init__(self, ls, poses, istamps, gyro, accel, gyro_bias, offset_s, ia, ib, ic) -> None:
        t = [(ls[i] - ls[0]) / NS_PER_S for i in (ia, ib, ic)]  # LiDAR clock, relative
        self.dd_p = second_divided_difference(poses[ia, :3, 3], poses[ib, :3, 3], poses[ic, :3, 3], *t)
        self.dd_R = second_divided_difference(poses[ia, :3, :3], poses[ib, :3, :3], poses[ic, :3, :3], *t)
        self.R_b = poses[ib, :3, :3]
        wa, wc = 2.0 / ((t[2] - t[0]) * (t[1] - t[0])), 2.0 / ((t[2] - t[0]) * (t[2] - t[1]))
        self.pose_idx = np.column_stack([ia, ib, ic])
        self.pose_w = np.column_stack([wa, -(wa + wc), wc])
        g = GyroOrientation(istamps, gyro, gyro_bias)
        s = [g.relative_s(ls[i], offset_s) for i in (ia, ib, ic)]  # IMU clock
        Gt = np.swapaxes(g.at(s[1]), 1, 2)
        F = PiecewiseLinear(g.t_s, np.einsum("nij,nj->ni", g.G, accel))
        Gs = PiecewiseLinear(g.t_s, g.G)
        self.A = np.einsum("nij,nj->ni", Gt, F.hat_average(*s))
        self.C = Gt @ Gs.hat_average(*s)


class _Whitener:
    """Covariance of the windows' residuals (the same for each world axis): per-pose position noise through the
    DD weights (windows sharing poses correlate) plus white noise, both levels maximum-likelihood."""

    def __init__(self, idx: np.ndarray, wts: np.ndarray, r: np.ndarray) -> None:
        n = len(idx)
        self.D = np.zeros((3, n))  # lower bands of D D^T: [d, j] = (D D^T)[j + d, j]
        for d in range(3):
            for s1 in range(3):
                for s2 in range(3):
                    same = idx[: n - d, s1] == idx[d:, s2]
                    self.D[d, : n - d] += np.where(same, wts[: n - d, s1] * wts[d:, s2], 0.0)
        v = max(float((r * r).mean()), 1e-12)
        x0 = np.log([0.9 * v / self.D[0].mean(), 0.1 * v])
        self.lo = x0 + np.log(1e-6)  # a level vanishing would make the whitening blow up
        best = minimize(lambda q: self._nll(q, r), x0, method="Nelder-Mead", options={"xatol": 1e-3, "fatol": 1e-6})
        q = np.exp(np.maximum(best.x, self.lo))
        self.L = self._cholesky(q)
        self.levels = np.sqrt(q)  # (position sigma, white sigma)

    def _cholesky(self, q: np.ndarray) -> np.ndarray:
        ab = q[0] * self.D
        ab[0] = ab[0] + q[1]
        return cholesky_banded(ab, lower=True)

    def _nll(self, q: np.ndarray, r: np.ndarray) -> float:
        try:
            L = self._cholesky(np.exp(np.maximum(q, self.lo)))
        except np.linalg.LinAlgError:
            return 1e300
        z = solve_banded((2, 0), L, r)
        return float(r.shape[1] * np.log(L[0]).sum() + 0.5 * (z * z).sum())

    def __call__(self, M: np.ndarray) -> np.ndarray:
        """Whiten (n, ...) along the windows."""
        return solve_banded((2, 0), self.L, M.reshape(len(M), -1)).reshape(M.shape)


def _rows(w: _Windows, sel: np.ndarray, x: np.ndarray, R: np.ndarray, refine: bool) -> tuple[np.ndarray, np.ndarray]:
    """Residuals (n,3) and Jacobian (n,3,p) at x = [t, b_a, g(, d)], unwhitened."""
    t, ba, g = x[:3], x[3:6], x[6:9]
    Rb = w.R_b[sel]
    A = w.A[sel] - np.einsum("nij,j->ni", w.C[sel], ba)
    v = A @ R.T  # R (A - C b_a), LiDAR frame
    r = w.dd_p[sel] + np.einsum("nij,j->ni", w.dd_R[sel], t) - np.einsum("nij,nj->ni", Rb, v) - g
    cols = [w.dd_R[sel], (Rb @ R) @ w.C[sel], np.broadcast_to(-np.eye(3), (len(v), 3, 3))]
    if refine:
        cols.append(Rb @ skew(v))
    return r, np.concatenate(cols, axis=2)


def _solve(w: _Windows, keep: np.ndarray, R0: np.ndarray, refine: bool, rot_cov: np.ndarray | None,
           prior_t: np.ndarray, prior_sigma_m: float, iterations: int = 4):
    """Gauss-Newton under the windows' noise covariance; returns (x = [t, b_a, g(, d)], R, normal matrix with
    the priors, whose inverse is the covariance)."""
    p = 12 if refine else 9
    x = np.zeros(p)
    x[:3] = prior_t
    R = R0.copy()
    if refine:  # an angle the prior hardly knows may be far off: start the iterations from the best one about it
        x[9:] = _best_turn(w, keep, R0, rot_cov, x)
        R = so3_exp(x[9:]) @ R0
    # linear in lever arm, bias and gravity: solve, take the noise levels from the residuals, solve under them,
    # and again (the unweighted fit's residuals overstate the white part)
    r, J = _rows(w, keep, x, R, False)
    x[:9] += -np.linalg.lstsq(J.reshape(-1, 9), r.reshape(-1), rcond=None)[0]
    for _ in range(NOISE_ROUNDS):
        r, J = _rows(w, keep, x, R, False)
        whiten = _Whitener(w.pose_idx[keep], w.pose_w[keep], r)
        rw, Jw = whiten(r), whiten(J)
        H9 = np.einsum("nji,njk->ik", Jw, Jw)
        H9[:3, :3] += np.eye(3) / prior_sigma_m**2
        g9 = np.einsum("nji,nj->i", Jw, rw)
        g9[:3] += (x[:3] - prior_t) / prior_sigma_m**2
        x[:9] -= np.linalg.solve(H9, g9)
    info = np.zeros((p, p))
    info[:3, :3] = np.eye(3) / prior_sigma_m**2
    if refine:
        info[9:, 9:] = np.linalg.inv(rot_cov)
    for it in range(iterations + 1):
        r, J = _rows(w, keep, x, R, refine)
        r, J = whiten(r), whiten(J)
        H = np.einsum("nji,njk->ik", J, J) + info
        if it == iterations:
            return x, R, H, info, np.einsum("nji,nj->ni", J, r)
        g = np.einsum("nji,nj->i", J, r)
        g[:3] += info[:3, :3] @ (x[:3] - prior_t)
        if refine:
            g[9:] += info[9:, 9:] @ x[9:]
        step = -np.linalg.solve(H, g)
        x = x + step
        if refine:  # fold the rotation correction into R; x[9:] keeps the total departure from the prior
            R = so3_exp(step[9:]) @ R
    raise AssertionError("unreachable")


def _best_turn(w: _Windows, keep: np.ndarray, R0: np.ndarray, rot_cov: np.ndarray, x: np.ndarray) -> np.ndarray:
    """The rotation vector (about the prior's weakest direction, zero when its 1-sigma is below ``SEARCH_SIGMA_RAD``)
    whose mounting best explains the accelerations, lever arm, bias and gravity solved for each angle of a grid."""
    val, vec = np.linalg.eigh(0.5 * (rot_cov + rot_cov.T))
    if np.sqrt(max(val[-1], 0.0)) < SEARCH_SIGMA_RAD:
        return np.zeros(3)
    best, cost = np.zeros(3), np.inf
    for a in np.radians(np.arange(0.0, 360.0, SEARCH_STEP_DEG)):
        d = a * vec[:, -1]
        r, J = _rows(w, keep, x, so3_exp(d) @ R0, False)
        step = np.linalg.lstsq(J.reshape(-1, 9), r.reshape(-1), rcond=None)[0]
        c = float(np.sum((r.reshape(-1) - J.reshape(-1, 9) @ step) ** 2))
        if c < cost:
            best, cost = d, c
    return so3_log(so3_exp(best))  # within (-pi, pi]


def _honest_covariance(H: np.ndarray, info: np.ndarray, scores: np.ndarray, spans_ns: np.ndarray) -> np.ndarray:
    """The fit's covariance, never below what its whitened scores show: the noise model (white per-pose and
    IMU noise) misses slow registration errors (drift, a map following sways), which leave neighbouring windows'
    residuals correlated. The sandwich estimate over ``CORRELATION_S`` of neighbours takes that correlation (and
    the residuals' real size) into account; each variance is the larger of the two."""
    model = np.linalg.inv(H)
    lag = max(1, int(round(CORRELATION_S * NS_PER_S / max(float(np.median(spans_ns)) / 2.0, 1.0))))
    sandwich = sandwich_covariance(H, scores, lag=min(lag, len(scores) // 4), prior_info=info)
    return floored(sandwich, np.sqrt(np.maximum(np.diag(model), 0.0)))


def _explain(cov: np.ndarray, phi: np.ndarray, max_sigma_m: float, frame: str, notes: list[str],
             refuse: bool = True) -> None:
    weak = weak_directions(cov, max_sigma_m)
    advice = "rotate the sensor briskly about all three axes (sweeps of +-30 deg at about 1 Hz) while recording"
    if len(weak) == 3 and refuse:
        raise InputError(f"too little rotation to estimate the {frame}-IMU lever arm (1-sigma {100 * weak[-1][1]:.0f} cm "
                         f"or worse along every axis): {advice}")
    if len(weak) == 3:  # the accelerations' fit still refines the rotation; the lever arm is named as a whole
        notes.append(f"the lever arm (T_base_imu translation) is not observable: too little rotation (1-sigma "
                     f"{100 * weak[-1][1]:.0f} cm or worse along every axis): {advice}")
        return
    axis, share = dominant_rotation_axis(phi)
    for v, s in weak:
        why = ("the platform turned only about that axis, as a ground vehicle turning about the vertical does"
               if turned_mostly_about(v, axis, share) else "the motion barely turned about the other axes")
        notes.append(f"the lever arm along {axis_name(v, frame)} is not observable (1-sigma {100 * s:.0f} cm; keep a "
                     f"measured value for it): {why}; tilt or roll the sensor while moving, or measure that component")
