"""Whether GPS has anything to say about the shape of an IMU + wheels trajectory (no odometry).

A consumer receiver's error is mostly slow (metres, correlated over a minute): over a short stretch it moves
the fixes as much as the wheels and gyro drift in that time, or more, and a fusion that takes it for white
noise bends a good dead reckoning towards it. So the trajectory fused without GPS is tested against the fixes
under the receiver's real error (``consistent``): a rigid fit in the plane (heading and shift, which GPS alone
gives), weighted by the error's covariance (a first-order Gauss-Markov part of ``SLOW_SHARE`` of the variance,
correlation time ``TAU_S``, plus white noise; the total sigma ``TRUE_OVER_CLAIMED`` times the larger of the
fixes' claimed sigma and the white noise their own second differences show: consumer receivers claim about a
third of their error, most of it slow), and its chi-square against the ``QUANTILE`` of its degrees of
freedom. Only for a receiver whose claim the filter's innovations showed optimistic (``gps_quality.GpsNoise``
raised it for ``OPTIMISTIC_SHARE`` of the fixes or more); an honest claim is fused as it is. Consistent: the motion sources' shape stands, GPS gives the world's heading and position (``onto``).
Not consistent (wheels that slipped, a gyro that drifted over a long log): GPS shapes the trajectory.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .gps_quality import white_sigma_m
from .timeline import Prepared

TAU_S = 60.0
SLOW_SHARE = 0.9
TRUE_OVER_CLAIMED = 3.0
QUANTILE_Z = 2.326  # one-sided 99 %: chi-square(dof) taken as normal, mean dof, sigma sqrt(2 dof)
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

    def to_dict(self) -> dict:
        return {"consistent": self.consistent, "chi2": round(self.chi2, 1), "dof": self.dof, "fixes": self.fixes}


def applies(prep: Prepared) -> bool:
    """IMU + wheels + GPS without odometry (odometry beside GPS has the graph's receiver chain)."""
    use = prep.use
    return (prep.gps is not None and prep.wheel is not None and "gps" in use and "wheel" in use
            and "odom" not in use and bool(use.get("imu")))


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


def consistent(prep: Prepared, stamps_ns: np.ndarray, poses: np.ndarray) -> ShapeTest | None:
    """The GPS-free trajectory (``poses`` at ``stamps_ns``) against the accepted fixes (module docstring)."""
    g = prep.gps
    ok = np.asarray(g.accepted, bool) & (g.stamps_ns >= stamps_ns[0]) & (g.stamps_ns <= stamps_ns[-1])
    idx = np.flatnonzero(ok)
    if len(idx) < MIN_FIXES or len(stamps_ns) < 2:
        return None
    idx = idx[np.unique(np.linspace(0, len(idx) - 1, min(len(idx), MAX_FIXES)).round().astype(int))]
    t = g.stamps_ns[idx]
    p = np.column_stack([np.interp(t, stamps_ns, poses[:, 0, 3]), np.interp(t, stamps_ns, poses[:, 1, 3])])
    white = white_sigma_m(g.stamps_ns[ok], g.position_enu_m[ok, :2])
    sigma = TRUE_OVER_CLAIMED * max(float(np.median(g.sigma_h_m[idx])), white)
    th, shift, chi2 = rigid_fit(p, g.position_enu_m[idx, :2], error_covariance((t - t[0]) * 1e-9, sigma))
    dof = 2 * len(idx) - 3
    T = np.eye(4)
    T[:2, :2] = [[np.cos(th), -np.sin(th)], [np.sin(th), np.cos(th)]]
    T[:2, 3] = shift
    return ShapeTest(bool(chi2 <= dof + QUANTILE_Z * np.sqrt(2.0 * dof)), float(chi2), dof, len(idx), T)
