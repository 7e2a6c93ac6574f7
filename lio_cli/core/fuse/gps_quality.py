"""GPS as receivers behave: horizontal and vertical trusted apart, multipath jumps rejected, the noise a
message claims checked against the innovations.

Before any filter runs (``assess_gps``, on ``Prepared.gps``): each fix's horizontal and vertical sigma (its
covariance, else ``NoiseOptions.gps_position_sigma_m`` and ``gps_vertical_sigma_m``), and an ``accepted`` mask
that leaves out multipath jumps: a fix-to-fix step that the track's own recent velocity (the slope through its
last fixes) cannot explain (more
than ``JUMP_SIGMAS`` times the steps' robust spread, and at least ``JUMP_MIN_M``) opens a jump; the fixes after
it stay out until a step brings the track back within that bound of where it was (consistency returns), or
``JUMP_MAX_S`` has passed (the new level is then kept: a receiver that changed satellites for good). Pauses
longer than ``DROPOUT_PERIODS`` periods are counted as dropouts: the motion sources bridge them.

While a filter runs (``GpsNoise``): a receiver's covariance is often optimistic (a third of the truth, or the
slow wander left out). The innovations over the last ``WINDOW`` fixes tell: their robust second moment less
the filter's own share ``H P H^T`` is the measurement's variance, and the larger of it and the claimed one is
used, horizontally and vertically apart (the altitude wanders by tens of metres on consumer receivers and
must not pull, or gate out, the horizontal).

Stale fixes (``drop_stale``, on the cleaned fixes, before the rest): a fix whose position is exactly the one before
it while the wheels or the odometry move faster than ``MOVING_MPS`` is a receiver repeating its last fix (a frozen
output, status still FIX): left out. At rest a repeated fix is still the right position (a receiver's static hold)
and is kept; without wheels or odometry nothing tells rest from motion and every fix is kept.

The jump test sees only the GPS track, whose velocity is noisy on a turning platform: it can miss a jump's end
and keep a good track out for ``JUMP_MAX_S``, while the motion sources drift. The filter re-admits a flagged
fix (``JumpReadmit``) when its own horizontal uncertainty exceeds the jump threshold (it cannot tell a jump
from its own drift), or after ``READMIT_RUN`` flagged fixes in a row each inside the tight ``READMIT_CHI2`` gate
or with its residual back within ``BACK_SHARE`` of the threshold of the last accepted fix's (the track agrees with the
filter again: the jump is over); the rest of that flagged stretch is then admitted too.
"""

from __future__ import annotations

from collections import deque

import numpy as np

from .inputs import GpsSeries, PoseSeries, WheelSeries
from .report import SourceReport

JUMP_SIGMAS = 5.0  # a step this many robust sigmas beyond the track's own motion is a jump
JUMP_MIN_M = 3.0  # ... and at least this long
JUMP_MAX_S = 30.0  # a jump lasting longer is the receiver's new level
DROPOUT_PERIODS = 5.0  # a pause this many median periods long is a dropout
VELOCITY_STEPS = 5  # the track's velocity: the slope through this many previous steps' fixes
WINDOW = 50  # innovations the measured noise is taken over
MIN_WINDOW = 10  # innovations needed before it counts
RAISE_RATIO = 2.0  # the measured variance replaces the claimed one only above this many times it, well
# beyond a window's own scatter about an honest claim
READMIT_RUN = 5  # flagged fixes in a row agreeing with the filter end a jump the track test missed
READMIT_CHI2 = 4.605  # 90 % quantile of a chi-square variable with 2 degrees of freedom
BACK_SHARE = 0.75  # a residual this share of the jump threshold from the one before the jump: the track is back
MOVING_MPS = 0.2  # the wheels or odometry this fast: a fix repeating the one before it is stale
SPEED_BASE_NS = 500_000_000  # the odometry's speed: its displacement over this long
MEDIAN_CHI2 = {1: 0.4549, 2: 1.3863}  # median of a chi-square variable with 1 and 2 degrees of freedom


def sigmas(gps: GpsSeries) -> tuple[np.ndarray, np.ndarray]:
    """Per-fix horizontal and vertical sigma (m) of the cleaned covariance (the defaults where it had none)."""
    cov = gps.cov_m2
    return np.sqrt(np.maximum(0.5 * (cov[:, 0, 0] + cov[:, 1, 1]), 0.0)), np.sqrt(np.maximum(cov[:, 2, 2], 0.0))


def _robust_step_sigma(p: np.ndarray, dt: np.ndarray) -> float:
    """Per-axis sigma of a step's white part: the second differences' median absolute deviation (a jump is
    two of them; the motion's accelerations over a few periods are far below the noise)."""
    if len(p) < 4:
        return 0.0
    v = np.diff(p, axis=0) / dt[:, None]
    s = np.diff(v, axis=0) * dt[1:, None]
    mad = np.median(np.abs(s - np.median(s, axis=0)), axis=0)
    return float(1.4826 * np.sqrt(np.mean(mad**2)) / np.sqrt(3.0))  # a step's error is a third of a 2nd diff's


def white_sigma_m(stamps_ns: np.ndarray, p_h: np.ndarray) -> float:
    """Per-axis sigma of the fixes' white noise, from their own second differences (no motion source needed)."""
    if len(stamps_ns) < 4:
        return 0.0
    return _robust_step_sigma(p_h, np.maximum(np.diff(stamps_ns) * 1e-9, 1e-6)) / np.sqrt(2.0)


def jump_threshold_m(stamps_ns: np.ndarray, p_h: np.ndarray) -> float:
    """The step error (m) beyond which ``find_jumps`` opens a jump."""
    if len(stamps_ns) < 4:
        return JUMP_MIN_M
    dt = np.maximum(np.diff(stamps_ns) * 1e-9, 1e-6)
    return max(JUMP_MIN_M, JUMP_SIGMAS * _robust_step_sigma(p_h, dt))  # on the norm: exp(-25/2) by chance


def find_jumps(stamps_ns: np.ndarray, p_h: np.ndarray) -> tuple[np.ndarray, int, int]:
    """(in_jump mask, jumps opened, jumps kept as the new level) for horizontal positions (N,2)."""
    n = len(stamps_ns)
    out = np.zeros(n, bool)
    if n < VELOCITY_STEPS + 2:
        return out, 0, 0
    dt = np.maximum(np.diff(stamps_ns) * 1e-9, 1e-6)
    period = float(np.median(dt))
    thr = jump_threshold_m(stamps_ns, p_h)
    t_s = (stamps_ns - stamps_ns[0]) * 1e-9
    recent: deque = deque([(t_s[0], p_h[0])], maxlen=VELOCITY_STEPS + 1)  # fixes on the current level
    offset, t_open, opened, kept = None, 0, 0, 0
    for k in range(1, n):
        if dt[k - 1] > DROPOUT_PERIODS * period:  # nothing to compare across a dropout
            recent.clear()
            recent.append((t_s[k], p_h[k]))
            if offset is not None:
                out[k] = True
            continue
        e = p_h[k] - p_h[k - 1] - _track_velocity(recent) * dt[k - 1]
        big = float(np.hypot(*e)) > thr
        if offset is None:
            if big and len(recent) >= 3:
                offset, t_open, opened = e.copy(), int(stamps_ns[k]), opened + 1
                out[k] = True
                _shift(recent, e, t_s[k], p_h[k])
                continue
        else:
            if big:
                offset = offset + e
            if float(np.hypot(*offset)) <= thr:  # back where the track was: consistency returns
                offset = None
            elif (stamps_ns[k] - t_open) * 1e-9 > JUMP_MAX_S:
                offset, kept = None, kept + 1
            else:
                out[k] = True
            if big:
                _shift(recent, e, t_s[k], p_h[k])
                continue
        recent.append((t_s[k], p_h[k]))
    return out, opened, kept


def _track_velocity(recent: deque) -> np.ndarray:
    """The GPS track's velocity: the least-squares slope through its recent fixes (a single step's is as noisy
    as two fixes, metres per period; the slope over a second is a few times steadier)."""
    if len(recent) < 2:
        return np.zeros(2)
    t = np.array([r[0] for r in recent])
    p = np.array([r[1] for r in recent])
    tc = t - t.mean()
    return (tc @ (p - p.mean(axis=0))) / max(float(tc @ tc), 1e-12)


def _shift(recent: deque, e: np.ndarray, t: float, p: np.ndarray) -> None:
    """The recent fixes moved by a jump's step ``e`` onto the new level, and the fix after it appended."""
    moved = [(tr, pr + e) for tr, pr in recent]
    recent.clear()
    recent.extend(moved)
    recent.append((t, p))


def motion_speed(stamps_ns: np.ndarray, wheel: WheelSeries | None, odom: PoseSeries | None) -> np.ndarray | None:
    """The platform's speed (m/s) at ``stamps_ns`` by the wheels and the odometry (the larger); None without
    either."""
    out = None
    if wheel is not None and len(wheel):
        v = wheel.velocity_mps
        ok = np.any(np.isfinite(v), axis=1)
        if np.any(ok):
            out = np.interp(stamps_ns, wheel.stamps_ns[ok], np.sqrt(np.nansum(v[ok] ** 2, axis=1)))
    if odom is not None and len(odom) > 1:  # over a baseline: a pose's noise over one period would read as speed
        t, p = odom.stamps_ns, odom.poses[:, :3, 3]
        ends = [np.stack([np.interp(stamps_ns + d, t, p[:, k]) for k in range(3)], axis=1)
                for d in (-SPEED_BASE_NS // 2, SPEED_BASE_NS // 2)]
        s = np.linalg.norm(ends[1] - ends[0], axis=1) / (SPEED_BASE_NS * 1e-9)
        out = s if out is None else np.maximum(out, s)
    return out


def drop_stale(gps: GpsSeries, wheel: WheelSeries | None, odom: PoseSeries | None, report: SourceReport,
               notes: list[str]) -> GpsSeries:
    """``gps`` (cleaned) without its stale fixes (module docstring), rejected as ``stale_fix``, a note saying so."""
    speed = motion_speed(gps.stamps_ns, wheel, odom) if len(gps) > 1 else None
    if speed is None:
        return gps
    same = np.zeros(len(gps), bool)
    same[1:] = np.all(gps.position_enu_m[1:] == gps.position_enu_m[:-1], axis=1)
    stale = same & (speed > MOVING_MPS)
    n = int(np.count_nonzero(stale))
    if not n:
        return gps
    report.reject("stale_fix", n)
    notes.append(f"gps: {n} fixes left out: each repeats the fix before it exactly while the wheels or odometry "
                 f"move (over {MOVING_MPS:g} m/s): a receiver repeating its last position")
    keep = ~stale
    return GpsSeries(gps.stamps_ns[keep], gps.position_enu_m[keep], gps.cov_m2[keep], gps.valid[keep],
                     antenna_m=gps.antenna_m)


def assess_gps(gps: GpsSeries, report: SourceReport, jumps_ns: np.ndarray | None = None) -> GpsSeries:
    """``gps`` (cleaned) with ``sigma_h_m``, ``sigma_v_m`` and ``accepted`` filled in; jumps and dropouts
    counted. ``jumps_ns``: the stamps of the fixes a whole log's test found in jumps (a piece of it sees no jump
    that opened before it), instead of testing these fixes."""
    gps.sigma_h_m, gps.sigma_v_m = sigmas(gps)
    if jumps_ns is None:
        jump, opened, kept = find_jumps(gps.stamps_ns, gps.position_enu_m[:, :2])
    else:
        jump = np.isin(gps.stamps_ns, jumps_ns)
        opened, kept = int(np.count_nonzero(jump & ~np.r_[False, jump[:-1]])), 0
    gps.accepted = ~jump
    report.reject("multipath_jump", int(np.count_nonzero(jump)))
    report.note("jumps", opened)
    report.note("jump_kept", kept)
    if len(gps) > 2:
        dt = np.diff(gps.stamps_ns)
        report.note("dropouts", int(np.count_nonzero(dt > DROPOUT_PERIODS * np.median(dt))))
    return gps


class JumpReadmit:
    """Whether a fix is used: every accepted one, and a flagged one (a jump) once the filter says the filter,
    not the fix, is off (module docstring). One per filter pass."""

    def __init__(self, gps: GpsSeries, report: SourceReport):
        self.accepted, self.report = gps.accepted, report
        self.thr2 = jump_threshold_m(gps.stamps_ns, gps.position_enu_m[:, :2]) ** 2 if len(gps) else 0.0
        self.run, self.open = 0, False
        self.r_before: np.ndarray | None = None  # the residual of the last accepted fix

    def __call__(self, i: int, r_h: np.ndarray, hph: np.ndarray, var: float) -> bool:
        """Fix ``i``, its horizontal residual ``r_h`` against the filter, ``hph`` = H P H^T (2x2) and the
        fix's variance per axis ``var``."""
        if self.accepted[i]:
            self.run, self.open, self.r_before = 0, False, r_h
            return True
        if not self.open:
            if 0.5 * float(np.trace(hph)) > self.thr2:  # the filter knows less than a jump's size
                return self._readmit()
            d2 = float(r_h @ np.linalg.solve(hph + var * np.eye(2), r_h))
            # the residual back near its level before the jump (a jump is at least the threshold): the track returned
            back = self.r_before is not None and float(np.sum((r_h - self.r_before) ** 2)) <= BACK_SHARE**2 * self.thr2
            self.run = self.run + 1 if d2 <= READMIT_CHI2 or back else 0
            if self.run < READMIT_RUN:
                return False
            self.open = True
        return self._readmit()

    def _readmit(self) -> bool:
        self.report.rejected["multipath_jump"] -= 1
        if not self.report.rejected["multipath_jump"]:
            del self.report.rejected["multipath_jump"]
        self.report.note("jump_readmitted")
        return True


class GpsNoise:
    """The variance a GPS fix's residual is given: the claimed one, or more where the innovations say so
    (module docstring); one per axis group (``dof`` 2: horizontal, 1: vertical)."""

    def __init__(self, dof: int):
        self.dof = dof
        self.r2: deque = deque(maxlen=WINDOW)
        self.hph: deque = deque(maxlen=WINDOW)

    def variance(self, claimed: float) -> float:
        if len(self.r2) < MIN_WINDOW:
            return claimed
        measured = float(np.median(self.r2)) / MEDIAN_CHI2[self.dof] - float(np.mean(self.hph))
        return measured if measured > RAISE_RATIO * claimed else claimed

    def record(self, r: np.ndarray, hph_mean_var: float) -> None:
        """An innovation ``r`` (gated or not: the median shrugs off outliers) and the filter's own variance
        share (mean of the diagonal of ``H P H^T``)."""
        self.r2.append(float(r @ r))
        self.hph.append(hph_mean_var)


def noise_variance(noise: GpsNoise, r: np.ndarray, H: np.ndarray, P: np.ndarray, claimed: float,
                   report: SourceReport) -> float:
    """The variance per axis a fix's residual ``r`` (rows ``H``) enters with, given the window so far; the
    innovation is then added to the window."""
    var = noise.variance(claimed)
    if var > claimed and noise.dof == 2:
        report.note("noise_raised")
    hph = H.dot(P).dot(H.T)
    noise.record(np.asarray(r, float), float(np.trace(hph)) / len(r))
    return var
