"""Wheel odometry scale factors against LiDAR odometry, with slip episodes found and left out.

Scale factors are corrections: ``v_true = s_v v_wheel`` and ``w_true = s_w w_wheel + d_w v_wheel``. For a
differential drive whose odometry uses a nominal radius r0 and baseline b0 (``v = r (wl + wr) / 2``,
``w = r (wr - wl) / b``) with true wheel radii r_l, r_r (mean r) and baseline b: ``s_v = r / r0``,
``s_w = s_v b0 / b`` (so ``r = r0 s_v``, ``b = b0 s_v / s_w``) and ``d_w = (r_r - r_l) / (r0 b)``: unequal
wheels make a vehicle driving straight report a yaw rate proportional to its speed (and, turning, a small speed
error ``(r_r - r_l) b0 / (4 r0) w``, included when b0 is given).

Over consecutive windows of ``window_s`` the wheel speeds, corrected, are integrated on the plane into a
relative pose and compared with the base's relative pose from the trajectory (forward, lateral, yaw): exact
for any path shape. A robust fit (Cauchy loss) finds the
factors, windows whose residual is far out (slip: the wheels turn, the ground does not follow) are left out
and named, and a plain least squares on the rest gives the values and their 1-sigma (adjacent windows share a
pose: accounted for).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.linalg import cholesky_banded, solve_banded
from scipy.optimize import least_squares, minimize

from ...errors import InputError
from ...geometry import inv_pose, yaw_of
from .common import NS_PER_S, CalibrationResult, check_stamps, check_trajectory, true_runs

OUTLIER_SIGMAS = 4.0
MIN_DISTANCE_M = 2.0
WEAK_REL_SIGMA = 0.01
MAX_SCALE = 1.5  # a wheel odometry 50% off is not mis-calibrated but measuring something else


@dataclass(frozen=True, eq=False)
class WheelCalib(CalibrationResult):
    speed_scale: float  # s_v: true forward speed = s_v * wheel speed
    speed_scale_sigma: float
    yaw_rate_scale: float  # s_w: true yaw rate = s_w * wheel yaw rate + d_w * wheel speed
    yaw_rate_scale_sigma: float
    yaw_per_distance_radpm: float  # d_w
    yaw_per_distance_sigma_radpm: float
    radius_m: float | None  # mean wheel radius r0 * s_v when the nominal radius was given
    radius_sigma_m: float | None
    baseline_m: float | None  # b0 * s_v / s_w when the nominal baseline was given
    baseline_sigma_m: float | None
    radius_left_m: float | None  # r0 (s_v - d_w b / 2) when both nominal values were given
    radius_right_m: float | None  # r0 (s_v + d_w b / 2)
    slip_ns: tuple[tuple[int, int], ...]  # [start, end] of the windows left out as slip
    windows: int  # windows used
    distance_m: float  # path length of the windows used (LiDAR)
    turned_rad: float  # total |yaw change| of the windows used (LiDAR)
    notes: tuple[str, ...]


def estimate_wheel_scales(wheel_stamps_ns: np.ndarray, linear_mps: np.ndarray, angular_radps: np.ndarray,
                          traj_stamps_ns: np.ndarray, T_world_traj: np.ndarray, *,
                          T_base_traj: np.ndarray | None = None, radius_m: float | None = None,
                          baseline_m: float | None = None, window_s: float = 1.0) -> WheelCalib:
    """Scale factors of wheel odometry (forward speed and yaw rate of the base, on the trajectory's clock)
    against a trajectory of the frame ``traj`` (LiDAR odometry: pass ``T_base_traj`` = T_base_lidar; default:
    the trajectory is of the base)."""
    ws = check_stamps(wheel_stamps_ns, "wheel odometry", 3)
    v = np.asarray(linear_mps, np.float64).reshape(-1)
    w = np.asarray(angular_radps, np.float64).reshape(-1)
    if len(v) != len(ws) or len(w) != len(ws) or not (np.isfinite(v).all() and np.isfinite(w).all()):
        raise InputError("wheel odometry: speeds and yaw rates must be finite, one of each per stamp")
    ts, T = check_trajectory(traj_stamps_ns, T_world_traj)
    T_wb = T if T_base_traj is None else T @ inv_pose(np.asarray(T_base_traj, np.float64))
    inside = (ts >= ws[0]) & (ts <= ws[-1])
    ts, T_wb = ts[inside], T_wb[inside]
    k = max(1, int(round(window_s * NS_PER_S / np.median(np.diff(ts))))) if len(ts) > 2 else 1
    ia = np.arange(0, len(ts) - k, k)
    if len(ia) < 3:
        raise InputError(f"wheel odometry and trajectory share {len(ts)} poses: too little overlap for windows of "
                         f"{window_s:g} s (are they on the same clock?)")
    ib = ia + k
    R_rel = np.einsum("nji,njk->nik", T_wb[ia, :3, :3], T_wb[ib, :3, :3])
    rel_t = np.einsum("nji,nj->ni", T_wb[ia, :3, :3], T_wb[ib, :3, 3] - T_wb[ia, :3, 3])
    meas = np.column_stack([rel_t[:, 0], rel_t[:, 1], yaw_of(R_rel)])
    plane = _Plane(ws, v, w, ts[ia], ts[ib])

    cross = 0.0 if baseline_m is None else baseline_m**2 / 4.0  # e_v = d_w b0^2 s_v / (4 s_w)

    def resid(s: np.ndarray, sig: np.ndarray) -> np.ndarray:
        d = plane.relative(s[0], s[1], s[2], cross * s[2] * s[0] / s[1]) - meas
        d[:, 2] = np.mod(d[:, 2] + np.pi, 2.0 * np.pi) - np.pi
        return (d / sig).ravel()

    dist = np.linalg.norm(rel_t[:, :2], axis=1)
    if dist.sum() < MIN_DISTANCE_M:
        raise InputError(f"wheel scales: the platform moved {dist.sum():.1f} m while wheel odometry ran; drive at least "
                         f"{MIN_DISTANCE_M:g} m (better tens of metres, with turns both ways)")
    sig0 = np.array([0.02, 0.02, np.radians(0.3)])
    fit = least_squares(lambda s: resid(s, sig0), np.array([1.0, 1.0, 0.0]), loss="cauchy", f_scale=3.0)
    good = np.ones(len(ia), bool)
    # the scatter of the windows, once, from all of them (the median absolute deviation ignores the slips): one
    # re-measured on the windows kept after each cut shrinks with every cut and trims good windows in turn,
    # which made the result jump between draws of the same log
    r = resid(fit.x, sig0).reshape(-1, 3) * sig0
    scale = np.maximum(1.4826 * np.median(np.abs(r - np.median(r, axis=0)), axis=0), np.array([1e-4, 1e-4, 1e-5]))
    for it in range(4):  # flag far-out windows against that scatter, refit on the rest, repeat until stable
        new_good = ~(np.abs(r - np.median(r[good], axis=0)) > OUTLIER_SIGMAS * scale).any(axis=1)
        if it > 0 and (new_good == good).all():
            break
        good = new_good
        fit = least_squares(lambda s, sc=scale, g=good: resid(s, sc).reshape(-1, 3)[g].ravel(), fit.x)
        r = resid(fit.x, sig0).reshape(-1, 3) * sig0
    bad = ~good
    # generalised least squares: consecutive windows share a pose, so their position and heading noise cancel
    # along the path (what makes the whole distance, not each window's, set the speed scale's precision)
    gi = np.flatnonzero(good)
    adjacent = ib[gi[:-1]] == ia[gi[1:]]
    for _ in range(2):  # noise levels from the residuals, the scales under them, once more
        whiten = _Whitener(resid(fit.x, np.ones(3)).reshape(-1, 3)[good], T_wb[ia[gi], :3, :3], adjacent)
        fit = least_squares(lambda s, wh=whiten: wh(resid(s, np.ones(3)).reshape(-1, 3)[good]), fit.x)
    cov = np.linalg.inv(fit.jac.T @ fit.jac + np.eye(3))  # + a unit prior: a factor the motion never shows stays finite
    s_v, s_w, d_w = fit.x
    sv_sig, sw_sig, dw_sig = np.sqrt(np.diag(cov))
    if not (1 / MAX_SCALE < s_v < MAX_SCALE and 1 / MAX_SCALE < s_w < MAX_SCALE):
        # factors are corrections near one: far from it, the two disagree about the motion itself (a corridor
        # along which the LiDAR cannot see the platform move: speed scale 0.02 or negative, not 1.01)
        raise InputError(f"the wheels and the LiDAR trajectory disagree about the motion itself (speed scale "
                         f"{s_v:.3g}, yaw-rate scale {s_w:.3g}): the LiDAR did not see the distance travelled (a "
                         f"corridor or open ground along the way?) or the wheel topic is not this platform's")
    notes: list[str] = []
    if baseline_m is None:
        notes.append("no nominal baseline: the small speed error of unequal wheels while turning is not modelled")
    slips = tuple((int(ts[ia[a]]), int(ts[ib[b - 1]])) for a, b in true_runs(bad))
    if slips:
        t0 = ws[0]
        txt = ", ".join(f"{(a - t0) / NS_PER_S:.1f}-{(b - t0) / NS_PER_S:.1f} s" for a, b in slips)
        notes.append(f"wheel slip (or a bad registration) at {txt} after the first wheel stamp: left out")
    turned = float(np.abs(meas[good, 2]).sum())
    if sv_sig > WEAK_REL_SIGMA * s_v:
        notes.append(f"the speed scale is weakly determined (1-sigma {100 * sv_sig:.1f}%): drive further")
    if sw_sig > WEAK_REL_SIGMA * s_w:
        notes.append(f"the yaw-rate scale is weakly determined (1-sigma {100 * sw_sig:.1f}%; turned "
                     f"{np.degrees(turned):.0f} deg in all): turn more, both ways")
    radius = radius_sig = base = base_sig = r_left = r_right = None
    if radius_m is not None:
        radius, radius_sig = float(radius_m * s_v), float(radius_m * sv_sig)
    if baseline_m is not None:
        base = float(baseline_m * s_v / s_w)
        g = np.array([1.0 / s_w, -s_v / s_w**2, 0.0]) * baseline_m
        base_sig = float(np.sqrt(g @ cov @ g))
    if radius is not None and base is not None:
        r_left, r_right = float(radius_m * (s_v - d_w * base / 2)), float(radius_m * (s_v + d_w * base / 2))
    return WheelCalib(float(s_v), float(sv_sig), float(s_w), float(sw_sig), float(d_w), float(dw_sig), radius,
                      radius_sig, base, base_sig, r_left, r_right, slips, int(good.sum()), float(dist[good].sum()),
                      turned, tuple(notes))


class _Plane:
    """Wheel odometry integrated on the plane, corrected: relative (x, y, yaw) over each [ta, tb]."""

    def __init__(self, ws: np.ndarray, v: np.ndarray, w: np.ndarray, ta_ns: np.ndarray, tb_ns: np.ndarray) -> None:
        self.t = (ws - ws[0]) / NS_PER_S
        self.v, self.w = v, w
        self.ta = (ta_ns - ws[0]) / NS_PER_S
        self.tb = (tb_ns - ws[0]) / NS_PER_S
        dt = np.diff(self.t)
        self.dth = 0.5 * (w[1:] + w[:-1]) * dt  # heading step at unit yaw scale
        self.ds = 0.5 * (v[1:] + v[:-1]) * dt  # distance step at unit speed scale

    def relative(self, s_v: float, s_w: float, d_w: float = 0.0, e_v: float = 0.0) -> np.ndarray:
        """With v = s_v v_wheel + e_v w_wheel and w = s_w w_wheel + d_w v_wheel."""
        dth = s_w * self.dth + d_w * self.ds
        ds = s_v * self.ds + e_v * self.dth
        th = np.concatenate([[0.0], np.cumsum(dth)])
        mid = th[:-1] + 0.5 * dth
        sinc = np.sinc(0.5 * dth / np.pi)  # exact arc over each step
        x = np.concatenate([[0.0], np.cumsum(ds * np.cos(mid) * sinc)])
        y = np.concatenate([[0.0], np.cumsum(ds * np.sin(mid) * sinc)])
        xa, ya, tha = (np.interp(self.ta, self.t, q) for q in (x, y, th))
        xb, yb, thb = (np.interp(self.tb, self.t, q) for q in (x, y, th))
        c, s = np.cos(tha), np.sin(tha)
        dx, dy = xb - xa, yb - ya
        return np.column_stack([c * dx + s * dy, -s * dx + c * dy, thb - tha])


class _Whitener:
    """Whitens stacked window residuals (n,3) = (forward, lateral, yaw) under per-pose noise that adjacent
    windows share (position sigma_p, heading sigma_h: they cancel along the path) plus white noise per window.
    The four noise levels are the maximum-likelihood ones for the residuals given."""

    def __init__(self, r: np.ndarray, R_start: np.ndarray, adjacent: np.ndarray) -> None:
        self.n = len(r)
        self.P = np.einsum("nji,njk->nik", R_start[:-1], R_start[1:])[:, :2, :2]  # frame k -> frame k+1 (plane)
        self.adj = np.flatnonzero(adjacent)
        v = np.array([0.5 * (r[:, :2] ** 2).sum(axis=1).mean(), (r[:, 2] ** 2).mean()])
        v = np.maximum(v, 1e-12)
        x0 = np.log(np.concatenate([0.4 * v, 0.2 * v]))  # [sigma_p^2, sigma_h^2, white_xy, white_yaw]
        self.lo = np.log(np.concatenate([v, v]) * 1e-6)  # a level vanishing would make the whitening blow up
        best = minimize(lambda x: self._nll(x, r), x0, method="Nelder-Mead",
                        options={"xatol": 1e-3, "fatol": 1e-6, "maxiter": 800})
        self.L = self._cholesky(np.exp(np.maximum(best.x, self.lo)))

    def _cholesky(self, q: np.ndarray) -> np.ndarray:
        sp2, sh2, wxy, wh = q
        ab = np.zeros((6, 3 * self.n))  # lower band storage: ab[d, j] = S[j + d, j]
        ab[0] = np.tile([2 * sp2 + wxy, 2 * sp2 + wxy, 2 * sh2 + wh], self.n)
        k = self.adj
        j0 = 3 * k
        for di in range(2):  # block (k+1, k): -sigma_p^2 (R_k^T R_k+1)^T in the plane, -sigma_h^2 in yaw
            for dj in range(2):
                ab[3 + di - dj, j0 + dj] = -sp2 * self.P[k, dj, di]
        ab[3, j0 + 2] = -sh2
        return cholesky_banded(ab, lower=True)

    def _nll(self, x: np.ndarray, r: np.ndarray) -> float:
        try:
            L = self._cholesky(np.exp(np.maximum(x, self.lo)))
        except np.linalg.LinAlgError:
            return 1e300
        z = solve_banded((5, 0), L, r.reshape(-1))
        return float(np.log(L[0]).sum() + 0.5 * z @ z)

    def __call__(self, r: np.ndarray) -> np.ndarray:
        return solve_banded((5, 0), self.L, r.reshape(-1))
