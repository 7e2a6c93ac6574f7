"""The world's heading when GPS fixes define it and nothing else measures absolute yaw.

A first, GPS-free pass of the filter over the start of the run gives the path in the start's own frame
(yaw zero at the start); the rotation about z that best maps that path onto the GPS fixes (2D Kabsch) is
the start heading in ENU. Offline this look-ahead is free, and it spares the EKF a linearisation from a
heading that may be wrong by up to pi.

A moving start that no wheel or odometry measures starts the pass at zero velocity: its path is then off by
the unknown start velocity times t (and a tilt's acceleration times t^2 / 2), which the fit then takes as
unknowns too (``yaw_velocity_onto``): the start velocity in ENU comes from the same fit. Those terms take most of
the path, so its heading can be weak (tens of degrees off with a rotated IMU): ``tried_headings`` runs the
filter with the fixes from it and from headings around it, and keeps the one whose path stays nearest them.
"""

from __future__ import annotations

import math
from dataclasses import replace

import numpy as np

from ...geometry import so3_exp_one
from .timeline import GPS, OUT, Prepared

MIN_SPAN_M = 10.0  # the fixes must spread at least this far (and 10 GPS sigmas) to give a heading


def heading_prefix_end(prep: Prepared) -> int | None:
    """Stamp of the first fix far enough from the first one to fix the heading, or None (never)."""
    g = prep.gps
    if g is None or len(g) < 3:
        return None
    sigma = float(np.sqrt(np.median(np.einsum("nii->n", g.cov_m2[:, :2, :2]) / 2.0)))
    d = np.linalg.norm(g.position_enu_m[:, :2] - g.position_enu_m[0, :2], axis=1)
    far = np.flatnonzero(d > max(MIN_SPAN_M, 10.0 * sigma))
    return int(g.stamps_ns[far[0]]) if len(far) else None


def prefix_without_gps(prep: Prepared, t_end_ns: int) -> Prepared:
    """A copy of ``prep`` up to ``t_end_ns`` with GPS removed and outputs at the GPS stamps."""
    keep = (prep.times <= t_end_ns) & (prep.kinds != GPS) & (prep.kinds != OUT)
    gps_t = prep.gps.stamps_ns[(prep.gps.stamps_ns >= prep.t0_ns) & (prep.gps.stamps_ns <= t_end_ns)]
    times = np.concatenate([prep.times[keep], gps_t])
    kinds = np.concatenate([prep.kinds[keep], np.full(len(gps_t), OUT, np.int8)])
    index = np.concatenate([prep.index[keep], np.arange(len(gps_t))])
    order = np.lexsort((kinds, times))
    use = {k: v for k, v in prep.use.items() if k != "gps"}
    reports = {k: replace(v, rejected=dict(v.rejected), notes=dict(v.notes), by_kind={})
               for k, v in prep.reports.items()}
    return replace(prep, use=use, reports=reports, times=times[order], kinds=kinds[order], index=index[order],
                   out_stamps=gps_t)


def yaw_onto(path_xy: np.ndarray, fixes_xy: np.ndarray) -> float:
    """Rotation angle about z that best maps ``path_xy`` onto ``fixes_xy`` (both (N,2), centred here; the antenna's
    offset on the base left out: a fraction of a metre against the metres of track the fit needs)."""
    a = path_xy - path_xy.mean(axis=0)
    b = fixes_xy - fixes_xy.mean(axis=0)
    s = float(np.sum(a[:, 0] * b[:, 1] - a[:, 1] * b[:, 0]))
    c = float(np.sum(a[:, 0] * b[:, 0] + a[:, 1] * b[:, 1]))
    return math.atan2(s, c)


def _design(t_s: np.ndarray) -> np.ndarray:
    """The columns of ``yaw_velocity_onto``'s linear unknowns: velocity, acceleration, offset (x and y rows)."""
    n = len(t_s)
    A = np.zeros((2 * n, 6))
    for row, axis in ((slice(0, None, 2), 0), (slice(1, None, 2), 1)):
        A[row, axis], A[row, 2 + axis], A[row, 4 + axis] = t_s, 0.5 * t_s**2, 1.0
    return A


def velocity_at(path_xy: np.ndarray, fixes_xy: np.ndarray, t_s: np.ndarray, yaw: float) -> np.ndarray:
    """The ENU velocity ``w`` of ``yaw_velocity_onto``'s fit at a given ``yaw``."""
    c, s_ = math.cos(yaw), math.sin(yaw)
    b = (fixes_xy - path_xy @ np.array([[c, s_], [-s_, c]])).reshape(-1)
    return (np.linalg.pinv(_design(t_s)) @ b)[0:2]


def yaw_velocity_onto(path_xy: np.ndarray, fixes_xy: np.ndarray, t_s: np.ndarray) -> tuple[float, np.ndarray]:
    """(yaw, w): the rotation about z and the ENU velocity w of the best fit ``fixes = Rz path + w t + a t^2/2
    + c``: for each yaw on a 1 deg grid, w, a and c by linear least squares; the yaw of the least residual."""
    A = _design(t_s)
    pinv = np.linalg.pinv(A)
    best = (math.inf, 0.0, np.zeros(2))
    for yaw in np.radians(np.arange(-180.0, 180.0, 1.0)):
        c, s_ = math.cos(yaw), math.sin(yaw)
        b = (fixes_xy - path_xy @ np.array([[c, s_], [-s_, c]])).reshape(-1)
        sol = pinv @ b
        cost = float(np.sum((A @ sol - b) ** 2))
        if cost < best[0]:
            best = (cost, float(yaw), sol[0:2])
    return best[1], best[2]


HYPOTHESES = 12  # start headings tried at a moving start nothing but the IMU measures (30 deg apart)
CHECK_PREFIX = 3  # the tries run over this many times the heading fit's prefix (with the fixes)


def prefix_with_gps(prep: Prepared, t_end_ns: int) -> Prepared:
    """A copy of ``prep`` up to ``t_end_ns`` (GPS kept, its reports copied) with outputs at the GPS stamps."""
    keep = (prep.times <= t_end_ns) & (prep.kinds != OUT)
    gps_t = prep.gps.stamps_ns[(prep.gps.stamps_ns >= prep.t0_ns) & (prep.gps.stamps_ns <= t_end_ns)]
    times = np.concatenate([prep.times[keep], gps_t])
    kinds = np.concatenate([prep.kinds[keep], np.full(len(gps_t), OUT, np.int8)])
    index = np.concatenate([prep.index[keep], np.arange(len(gps_t))])
    order = np.lexsort((kinds, times))
    reports = {k: replace(v, rejected=dict(v.rejected), notes=dict(v.notes), by_kind={})
               for k, v in prep.reports.items()}
    return replace(prep, reports=reports, times=times[order], kinds=kinds[order], index=index[order],
                   out_stamps=gps_t)


def check_end(prep: Prepared, t_end_ns: int) -> int:
    """Where the tries of ``best_heading`` stop: ``CHECK_PREFIX`` times the fit's prefix, within the log."""
    return int(min(prep.t0_ns + CHECK_PREFIX * (t_end_ns - prep.t0_ns), prep.t1_ns))


def miss(prep: Prepared, knots: dict, xy: slice) -> float:
    """Median horizontal distance of a try's path (its outputs at the fixes) from the accepted fixes over its
    second half: a wrong start heading leaves the filter rejecting fixes and drifting off them."""
    k = np.searchsorted(prep.gps.stamps_ns, knots["t_ns"])
    ok = prep.gps.accepted[k] & (np.arange(len(k)) >= len(k) // 2)
    if not ok.any():
        return math.inf
    # the base's path against the antenna's fixes: the antenna's offset moves every try alike
    d = knots["x_filt"][ok][:, xy] - prep.gps.position_enu_m[k[ok], :2]
    return float(np.median(np.linalg.norm(d, axis=1)))


def turned(start, yaw: float) -> None:
    """The start (``initial.Start``) turned by ``yaw`` about z, its world yaw now the GPS's, in place."""
    Rz = so3_exp_one(np.array([0.0, 0.0, yaw]))
    start.R, start.v, start.yaw_from = Rz @ start.R, Rz @ start.v, "gps"


def tried_headings(prep: Prepared, o, filter_cls, xy: slice, start, t_end_ns: int, fit, yaw: float
                   ) -> tuple[float, np.ndarray, str]:
    """At a moving start only the IMU measures, the fit's heading is weak (its start velocity and a constant
    acceleration take most of the path): the filter (``filter_cls`` with options ``o``) with the fixes runs from
    it and from ``HYPOTHESES - 1`` headings around it, each with the fit's velocity at that heading, up to
    ``check_end``; the one whose path stays nearest the fixes (``miss``) is kept. ``fit``: the heading fit's
    (path, fixes, seconds). Returns (yaw, velocity, a note for the start's reason)."""
    path, fixes, t_s = fit
    pre = prefix_with_gps(prep, check_end(prep, t_end_ns))
    best = (math.inf, yaw, velocity_at(path, fixes, t_s, yaw))
    for y in (yaw + np.radians(np.arange(HYPOTHESES) * 360.0 / HYPOTHESES)).tolist():
        w = velocity_at(path, fixes, t_s, y)
        s = replace(start, R=start.R.copy(), v=start.v.copy())
        turned(s, y)
        s.v[:2] += w
        score = miss(pre, filter_cls(pre, o, s).run(), xy)
        if score < best[0]:
            best = (score, math.atan2(math.sin(y), math.cos(y)), w)
    note = "" if abs(best[1] - math.atan2(math.sin(yaw), math.cos(yaw))) < 1e-9 else \
        f" (of {HYPOTHESES} headings tried with the fixes, the one they follow)"
    return best[1], best[2], note
