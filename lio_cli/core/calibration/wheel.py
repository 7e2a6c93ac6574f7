"""Wheel odometry scale factors against LiDAR odometry, with slip episodes found and left out.

Scale factors are corrections: ``v_true = s_v v_wheel`` and ``w_true = s_w w_wheel + d_w v_wheel``. For a
differential drive whose odometry uses a nominal radius r0 and baseline b0 (``v = r (wl + wr) / 2``,
``w = r (wr - wl) / b``) with true wheel radii r_l, r_r (mean r) and baseline b: ``s_v = r / r0``,
``s_w = s_v b0 / b`` (so ``r = r0 s_v``, ``b = b0 s_v / s_w``) and ``d_w = (r_r - r_l) / (r0 b)``: unequal
wheels make a vehicle driving straight report a yaw rate proportional to its speed (and, turning, a small speed
error ``(r_r - r_l) b0 / (4 r0) w``, included when b0 is given).

Over consecutive windows of ``window_s`` the wheel speeds, corrected, are integrated on the plane into a
relative pose and compared with the base's relative pose from the trajectory (forward, lateral, yaw): exact
for any path shape. A robust fit (Cauchy loss) finds the factors; windows whose residual is far out are either
a badly registered pose (the windows on either side make up for each other: joined, skipping it) or slip (the
wheels turn, the ground does not follow: left out and named); a generalised least squares on the rest gives the
values and their 1-sigma (adjacent windows share a pose: accounted for). Chains of windows starting at each
pose of the first window are fitted alike and averaged (``wheel_windows``).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ...errors import InputError
from ...geometry import inv_pose
from .common import NS_PER_S, CalibrationResult, check_stamps, check_trajectory, true_runs
from .wheel_windows import Chain, Plane, Windows, fit_chain

MIN_DISTANCE_M = 2.0
WEAK_REL_SIGMA = 0.01
MAX_WINDOWS = 1000  # windows of all chains together (a chain has one per window_s of the log)
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
    windows: int  # windows used (a bridged pair counts once)
    distance_m: float  # path length of the windows used (LiDAR)
    turned_rad: float  # total |yaw change| of the windows used (LiDAR)
    bridged: int  # badly registered LiDAR poses skipped by joining the windows on either side (any chain)
    notes: tuple[str, ...]

    def corrected(self, linear_mps: np.ndarray, angular_radps: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """The wheels' forward speed and yaw rate with these scales applied (the base's true ones)."""
        linear = np.asarray(linear_mps, float)
        return (self.speed_scale * linear,
                self.yaw_rate_scale * np.asarray(angular_radps, float) + self.yaw_per_distance_radpm * linear)


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
    cross = 0.0 if baseline_m is None else baseline_m**2 / 4.0  # e_v = d_w b0^2 s_v / (4 s_w)
    windows = Windows(Plane(ws, v, w), ts, T_wb, ia, ia + k, cross)
    dist = np.linalg.norm(windows.meas[:, :2], axis=1)
    if dist.sum() < MIN_DISTANCE_M:
        raise InputError(f"wheel scales: the platform moved {dist.sum():.1f} m while wheel odometry ran; drive at least "
                         f"{MIN_DISTANCE_M:g} m (better tens of metres, with turns both ways)")
    first = fit_chain(windows)
    # one chain uses every k-th pose and scan-to-scan jitter is largely independent, so the chains starting at the
    # poses in between are fitted too (with the first chain's noise levels) and averaged; a long log fits fewer
    starts = np.unique(np.linspace(0, k, min(k, max(1, MAX_WINDOWS // len(ia))), endpoint=False).astype(int))
    chains = [first] + [fit_chain(windows.with_windows(ia + j, ia + k + j), first.levels)
                        for j in starts[1:] if ia[-1] + k + j < len(ts)]
    x = np.mean([c.x for c in chains], axis=0)
    cov = np.mean([c.cov for c in chains], axis=0)  # as if the chains agreed entirely: a bound, not an estimate
    bad_runs = _voted_slips(chains, len(ts))
    win = first.win
    s_v, s_w, d_w = x
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
    slips = tuple((int(ts[a]), int(ts[b])) for a, b in bad_runs)
    if slips:
        t0 = ws[0]
        txt = ", ".join(f"{(a - t0) / NS_PER_S:.1f}-{(b - t0) / NS_PER_S:.1f} s" for a, b in slips)
        notes.append(f"wheel slip (or a bad registration) at {txt} after the first wheel stamp: left out")
    turned = float(np.abs(win.meas[:, 2]).sum())
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
                      radius_sig, base, base_sig, r_left, r_right, slips, len(win.ia),
                      float(np.linalg.norm(win.meas[:, :2], axis=1).sum()), turned,
                      len(set().union(*(c.skipped for c in chains))), tuple(notes))


def _voted_slips(chains: list[Chain], n: int) -> list[tuple[int, int]]:
    """Pose index ranges that at least half of the chains leave out as slip (a bad pose that one chain cannot
    bridge is not a slip for the others)."""
    votes = np.zeros(n, int)
    for c in chains:
        for a, b in c.slips:
            votes[a:b + 1] += 1
    return [(a, b - 1) for a, b in true_runs(2 * votes >= len(chains))]
