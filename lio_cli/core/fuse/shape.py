"""Whether GPS has anything to say about the shape of an IMU + wheels trajectory (no odometry).

A consumer receiver's error is mostly slow (metres, correlated over a minute): over a short stretch it moves the
fixes as much as the wheels and gyro drift in that time, or more, and a fusion that takes it for white noise bends a
good dead reckoning towards it. So the trajectory fused without GPS is tested against the fixes under the receiver's
real error (``consistent``): a rigid fit in the plane (heading and shift, which GPS alone gives), weighted by the
error's covariance (a first-order Gauss-Markov part of ``SLOW_SHARE`` of the variance, correlation time ``TAU_S``,
plus white noise; the total sigma ``TRUE_OVER_CLAIMED`` times the larger of the fixes' claimed sigma and the white
noise their own second differences show: consumer receivers claim about a third of their error, most of it slow),
and its chi-square against the ``QUANTILE`` of its degrees of freedom. That sum spreads a bend over hundreds of
fixes' white noise, so the heading drift a gyro bias leaves (the track's increments turned by a rate times time) is
tested on its own too, and so is a scale of the track (an unmeasured wheel radius): the chi-square each removes
against ``CHI2_1_99`` of one degree of freedom. Only for a receiver whose claim looks optimistic: the filter's
innovations showed it (``gps_quality.GpsNoise`` raised it for ``OPTIMISTIC_SHARE`` of the fixes or more), the IMU
verified the wheels' speed and yaw rate (``agreement``), or the fixes scatter about the GPS-free track beyond their
claimed sigma (``ShapeTest.claim_exceeded``: a filter that follows a slow error shows no optimism in its
innovations) where the IMU backs the wheels' speed (``agreement``: wrong wheels beside an honest receiver scatter the
fixes too); an honest claim is fused as it is. Consistent: the motion sources' shape stands, GPS gives the world's
heading and position. Not consistent (wheels that slipped, a gyro that drifted): GPS shapes the trajectory.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .gps_quality import white_sigma_m
from .inputs import GpsSeries, at_antenna
from .timeline import Prepared

TAU_S = 60.0
SLOW_SHARE = 0.9
TRUE_OVER_CLAIMED = 3.0
QUANTILE_Z = 2.326  # one-sided 99 %: chi-square(dof) taken as normal, mean dof, sigma sqrt(2 dof)
CHI2_1_99 = 6.635  # 99 % of chi-square with one degree of freedom
OPTIMISTIC_SHARE = 0.1
MIN_FIXES = 10
MAX_FIXES = 600  # evenly thinned: the covariance is dense


@dataclass
class ShapeTest:
    consistent: bool
    chi2: float
    dof: int
    fixes: int
    T: np.ndarray  # 4x4 moving the GPS-free trajectory onto the fixes (rotation about z, shift)
    drift_chi2: float = 0.0  # what a heading drift removes from the chi-square (``heading_drift``)
    drift_radps: float = 0.0  # that drift's rate
    claim_exceeded: bool = False  # the fixes' scatter about the fitted track beyond their claimed sigma (white)
    scale_chi2: float = 0.0  # what a scale of the track removes from the chi-square (``track_scale``)
    scale_off: float = 0.0  # that scale less 1

    def to_dict(self) -> dict:
        return {"consistent": self.consistent, "chi2": round(self.chi2, 1), "dof": self.dof, "fixes": self.fixes,
                "drift_chi2": round(self.drift_chi2, 2), "drift_radps": float(f"{self.drift_radps:.3g}"),
                "claim_exceeded": self.claim_exceeded, "scale_chi2": round(self.scale_chi2, 2),
                "scale_off": float(f"{self.scale_off:.3g}")}


def applies(prep: Prepared, estimator: str) -> bool:
    """IMU + wheels + GPS, without odometry unless the planar filter runs beside it (the wheels agree with it:
    ``choose``); odometry beside GPS and the 3D filter has the graph's receiver chain."""
    use = prep.use
    return (prep.gps is not None and prep.wheel is not None and "gps" in use and "wheel" in use
            and ("odom" not in use or estimator == "planar") and bool(use.get("imu")))


def error_covariance(t_s: np.ndarray, sigma: float, tau_s: float = TAU_S, slow_share: float = SLOW_SHARE) -> np.ndarray:
    """(N,N) covariance of one axis of the receiver error at ``t_s``: Gauss-Markov plus white."""
    slow = slow_share * sigma**2 * np.exp(-np.abs(t_s[:, None] - t_s[None, :]) / tau_s)
    return slow + (1.0 - slow_share) * sigma**2 * np.eye(len(t_s))


def rigid_fit(p: np.ndarray, z: np.ndarray, C: np.ndarray) -> tuple[float, np.ndarray, float]:
    """(heading, shift, chi-square) of ``z ~ R(heading) p + shift`` (N,2 each), each axis's error of
    covariance ``C``; the heading from the similarity fit's angle, then the shift again for that heading."""
    L = np.linalg.cholesky(C)
    w = lambda M: np.linalg.solve(L, M)  # noqa: E731  whitening
    n = len(p)
    one, zero = np.ones(n), np.zeros(n)
    A = np.vstack([w(np.column_stack([p[:, 0], -p[:, 1], one, zero])), w(np.column_stack([p[:, 1], p[:, 0], zero, one]))])
    b = np.concatenate([w(z[:, 0]), w(z[:, 1])])
    sol = np.linalg.lstsq(A, b, rcond=None)[0]
    th = float(np.arctan2(sol[1], sol[0]))
    c, s = np.cos(th), np.sin(th)
    q = p @ np.array([[c, s], [-s, c]])  # R(th) p, row-wise
    d = z - q
    Ad = np.vstack([w(np.column_stack([one, zero])), w(np.column_stack([zero, one]))])
    bd = np.concatenate([w(d[:, 0]), w(d[:, 1])])
    shift = np.linalg.lstsq(Ad, bd, rcond=None)[0]
    r = bd - Ad @ shift
    return th, shift, float(r @ r)


def _within(chi2: float, dof: int) -> bool:
    return chi2 <= dof + QUANTILE_Z * np.sqrt(2.0 * dof)


def heading_drift(p: np.ndarray, z: np.ndarray, C: np.ndarray, t_s: np.ndarray, heading: float) -> tuple[float, float]:
    """(chi-square removed, rate rad/s) by a heading drift of the track ``p`` (N,2) at ``t_s``: its increments turned
    by ``rate * t`` (linearised), fitted with a small turn and a shift about the rigid fit's ``heading``, each axis's
    error of covariance ``C``."""
    q, A, b, w = _linearised(p, z, C, heading)
    u = np.cumsum(t_s[:, None] * np.diff(q, axis=0, prepend=q[:1]), axis=0)  # sum of t dq
    removed, x = _removed(A, b, w(_turn(u)))
    return removed, -x  # the fit turns the track back: its drift is the opposite


def track_scale(p: np.ndarray, z: np.ndarray, C: np.ndarray, heading: float) -> tuple[float, float]:
    """(chi-square removed, scale - 1) by a scale of the track ``p`` (N,2) about its start (the wheels' speed scale
    an unmeasured radius leaves), fitted with a small turn and a shift about the rigid fit's ``heading``."""
    q, A, b, w = _linearised(p, z, C, heading)
    return _removed(A, b, w(q - q[0]))


def _turn(v: np.ndarray) -> np.ndarray:
    return np.column_stack([-v[:, 1], v[:, 0]])  # 90 degrees about z


def _linearised(p: np.ndarray, z: np.ndarray, C: np.ndarray, heading: float):
    """The track turned by ``heading``, the whitened design of a shift and a small turn, the whitened residual
    and the whitening of a (N,2) column."""
    c, s = np.cos(heading), np.sin(heading)
    q = p @ np.array([[c, s], [-s, c]])
    one, zero = np.ones(len(p)), np.zeros(len(p))
    L = np.linalg.cholesky(C)
    w = lambda M: np.concatenate([np.linalg.solve(L, M[:, 0]), np.linalg.solve(L, M[:, 1])])  # noqa: E731
    A = np.column_stack([w(np.column_stack([one, zero])), w(np.column_stack([zero, one])), w(_turn(q - q[0]))])
    return q, A, w(z - q), w


def _removed(A: np.ndarray, b: np.ndarray, col: np.ndarray) -> tuple[float, float]:
    """(chi-square the column ``col`` removes beside ``A``, its coefficient)."""
    r0 = b - A @ np.linalg.lstsq(A, b, rcond=None)[0]
    A1 = np.column_stack([A, col])
    x1 = np.linalg.lstsq(A1, b, rcond=None)[0]
    r1 = b - A1 @ x1
    return float(r0 @ r0 - r1 @ r1), float(x1[-1])


def consistent(g: GpsSeries, stamps_ns: np.ndarray, poses: np.ndarray) -> ShapeTest | None:
    """The GPS-free trajectory (``poses`` at ``stamps_ns``) against the accepted fixes ``g`` (assessed:
    ``Prepared.gps``; module docstring)."""
    ok = np.asarray(g.accepted, bool) & (g.stamps_ns >= stamps_ns[0]) & (g.stamps_ns <= stamps_ns[-1])
    idx = np.flatnonzero(ok)
    if len(idx) < MIN_FIXES or len(stamps_ns) < 2:
        return None
    idx = idx[np.unique(np.linspace(0, len(idx) - 1, min(len(idx), MAX_FIXES)).round().astype(int))]
    t = g.stamps_ns[idx]
    xy = at_antenna(poses[:, :3, :3], poses[:, :3, 3], g.lever)
    p = np.column_stack([np.interp(t, stamps_ns, xy[:, 0]), np.interp(t, stamps_ns, xy[:, 1])])
    white = white_sigma_m(g.stamps_ns[ok], g.position_enu_m[ok, :2])
    sigma = TRUE_OVER_CLAIMED * max(float(np.median(g.sigma_h_m[idx])), white)
    z, t_s = g.position_enu_m[idx, :2], (t - t[0]) * 1e-9
    C = error_covariance(t_s, sigma)
    th, shift, chi2 = rigid_fit(p, z, C)
    drift_chi2, rate = heading_drift(p, z, C, t_s, th)
    scale_chi2, scale_off = track_scale(p, z, C, th)
    dof = 2 * len(idx) - 3
    claimed = rigid_fit(p, z, np.diag(np.asarray(g.sigma_h_m[idx], float) ** 2))[2]
    T = np.eye(4)
    T[:2, :2] = [[np.cos(th), -np.sin(th)], [np.sin(th), np.cos(th)]]
    T[:2, 3] = shift
    ok = _within(chi2, dof) and drift_chi2 <= CHI2_1_99 and scale_chi2 <= CHI2_1_99
    return ShapeTest(bool(ok), float(chi2), dof, len(idx), T, drift_chi2=drift_chi2, drift_radps=rate,
                     claim_exceeded=not _within(claimed, dof), scale_chi2=scale_chi2, scale_off=scale_off)
