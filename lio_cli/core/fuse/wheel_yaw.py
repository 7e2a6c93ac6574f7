"""The wheels' yaw rate weighed against the gyro from the data (IMU gyro + wheel yaw rate, default selection).

Beside a gyro the wheels' yaw rate is left out by default: skid steering, a radius or baseline error and slips bias
it. But good wheels, or wheels whose scale error the data measure, measure the yaw rate without the gyro's bias,
which a moving start leaves unknown, and their heading is then the better one. ``weigh`` compares the two over the
log: the wheel yaw rate of each message against the gyro's z (base frame) averaged over the message's period,
``gyro - wheel = b_j + b'_j t + c gyro`` (a bias line per ``CHUNK_S``, ``c`` the wheels' yaw scale off the gyro's),
fitted by least squares with samples further than ``TRIM_Z`` robust sigmas trimmed (a run of them, a slip, widened
by ``TRIM_EDGE_S``: its edges below the trim bias ``c``). ``sigma_c`` is the larger of the fit's and a jackknife's
over ``JACKKNIFE_S`` blocks (at most ``MAX_BLOCKS``; none on a log shorter than ``MIN_BLOCKS`` blocks): a slip's
edges and the body's sway are correlated over seconds. The wheels' yaw rate enters when the fit measures their
scale (``2 sigma_c <= SCALE_TOL``; a skid-steered base's turning is not measured), that scale is a radius or
baseline error's (``|c| <= MAX_SCALE_OFF``), the residual does not follow the speed (unequal radii turn a straight
drive, which no scale holds; beyond ``SPEED_SHARE_Z`` sigmas, and more than ``SCALE_TOL`` of the yaw rate) and few
samples are far (``MAX_FAR_SHARE``); a scale further than ``RESOLVED_Z`` sigmas from 1 (a radius error of 3 % is
measured to about 0.02 %) is divided out, so a moving start's gyro bias is learned from the wheels all the same.
Its variance is the residual's robust variance less the averaged gyro's (the gyro's white noise from its own second
differences, over the wheel period), at least what the samples resolve (``RESOLVE_Z`` standard errors of the
residual's variance), plus the scale's share: ``(sigma_c w)^2`` where divided out, else ``((|c| + sigma_c) w)^2``;
it replaces the message's or the default (a driver's covariance can be pessimistic as well as optimistic). Samples
beyond the gate's sigmas of the residual lose their yaw rate (rejected as ``yaw_slip``); runs of them (a slip)
widened by ``SLIP_EDGE_S``. The gate's sigma is at least what the comparison cannot resolve: the averaged gyro's
noise and the gyro's yaw acceleration over half a wheel period (where in its period a wheel message took its rate).
Samples without a gyro mean (an IMU gap, outside its span) are never weighed: left out too (rejected as
``yaw_unchecked``).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from ..imu import running_integral
from ..robust import white_variance
from .yaw_fit import Fit, speed_share, widened

CHUNK_S = 60.0  # the gyro bias: a line per this long a stretch (it wanders slowly)
MIN_SPAN_S = 10.0  # shorter logs: the wheels' yaw rate stays out
MIN_SAMPLES = 200
MIN_YAW_RATE_RADPS = 0.05  # the drive must turn at least this fast somewhere, or the scale is not seen
SCALE_TOL = 0.005  # the wheels' yaw scale must be measured to this share (2 sigmas)
MAX_SCALE_OFF = 0.1  # and lie within this share of the gyro's (a radius or baseline error)
RESOLVED_Z = 2.0  # a scale further than this many sigmas from 1 is divided out
SPEED_SHARE_Z = 5.0  # a residual share of the speed beyond this many sigmas: unequal radii, the wheels left out
MAX_FAR_SHARE = 0.2  # more samples further than the gate from the gyro: the wheels' yaw rate stays out
RESOLVE_Z = 3.0  # the estimated variance is at least this many standard errors of the residual's variance
SLIP_EDGE_S = 0.25  # far samples widen by this on each side (a slip's onset and end are below the gate)
ACCEL_WINDOW_S = 0.1  # the gyro's yaw acceleration (the gate's floor) from its means over this long either side


@dataclass
class YawCheck:
    """What the check found (in the metrics as ``wheel_yaw_check``)."""

    used: bool = False
    why: str = ""
    scale_off: float | None = None  # c: gyro - wheel = bias + c * gyro
    scale_off_sigma: float | None = None
    scale_applied: bool = False  # the wheels' yaw rates divided by their scale (1 - c)
    speed_share: float | None = None  # the residual's share of the speed (unequal radii), rad/m
    speed_share_sigma: float | None = None
    sigma_radps: float | None = None  # the wheels' yaw-rate noise, estimated
    residual_sigma_radps: float | None = None
    far: int = 0
    unchecked: int = 0  # wheel yaw rates without a gyro mean to weigh them against (an IMU gap, outside its span)
    far_mask: np.ndarray | None = field(default=None, repr=False)  # per wheel sample, where used
    unchecked_mask: np.ndarray | None = field(default=None, repr=False)

    def to_dict(self) -> dict:
        r = lambda v, n=6: None if v is None else float(f"{v:.{n}g}")  # noqa: E731
        return {"used": self.used, "why": self.why, "scale_off": r(self.scale_off, 4),
                "scale_off_sigma": r(self.scale_off_sigma, 3), "scale_applied": self.scale_applied,
                "speed_share_radpm": r(self.speed_share, 4), "speed_share_sigma": r(self.speed_share_sigma, 3),
                "sigma_radps": r(self.sigma_radps, 3),
                "residual_sigma_radps": r(self.residual_sigma_radps, 3), "far_samples": self.far,
                "unchecked_samples": self.unchecked}


@dataclass
class Weighed:
    """One log's weighing, applied by stamp to a piece of it (a run fused in chunks weighs the whole log once, so
    every chunk uses its decision, noise and slips)."""

    check: dict  # YawCheck.to_dict()
    stamps_ns: np.ndarray | None = None  # the weighed wheel samples; None where the yaw rate stays out
    yaw: np.ndarray | None = None  # far and unchecked samples NaN
    var: np.ndarray | None = None
    far: np.ndarray | None = None
    unchecked: np.ndarray | None = None

    @classmethod
    def of(cls, stamps_ns: np.ndarray, check: YawCheck, yaw: np.ndarray | None, var: np.ndarray | None) -> Weighed:
        if yaw is None:
            return cls(check.to_dict())
        return cls(check.to_dict(), stamps_ns, yaw, var, check.far_mask, check.unchecked_mask)

    def on(self, stamps_ns: np.ndarray, yaw: np.ndarray) -> tuple[np.ndarray, np.ndarray, int, int] | None:
        """(the wheel yaw rates at these stamps, their variances, far and unchecked samples among them); a stamp
        the whole log's weighing has not seen is unchecked. None where the yaw rate stays out."""
        if self.yaw is None:
            return None
        i = np.minimum(np.searchsorted(self.stamps_ns, stamps_ns), len(self.stamps_ns) - 1)
        seen = self.stamps_ns[i] == stamps_ns
        out = np.where(seen, self.yaw[i], np.nan)
        unseen = int(np.count_nonzero(~seen & np.isfinite(yaw)))
        return out, self.var[i], int(np.count_nonzero(seen & self.far[i])), \
            int(np.count_nonzero(seen & self.unchecked[i])) + unseen


def _in_degrees(ratio: float) -> str:
    """A hint where the wheels' yaw rate over the gyro's is a radian over a degree (or its inverse), within 5 %."""
    deg = np.pi / 180.0
    if abs(ratio / deg - 1.0) < 0.05:
        return " (the gyro reads 57.3x the wheels: is the IMU's angular velocity in deg/s?)"
    if abs(ratio * deg - 1.0) < 0.05:
        return " (the wheels read 57.3x the gyro: is their yaw rate in deg/s?)"
    return ""


def _gyro_mean(ti: np.ndarray, gz: np.ndarray, gap: np.ndarray, a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """The gyro's mean over [a, b] (seconds, the IMU's trapezoid integral); NaN across an IMU gap."""
    G = running_integral(ti, gz)
    out = (np.interp(b, ti, G) - np.interp(a, ti, G)) / (b - a)
    out[(a < ti[0]) | (b > ti[-1])] = np.nan
    ga = np.cumsum(np.r_[0, gap.astype(np.int64)])  # gaps before each IMU sample
    crosses = np.interp(b, ti, ga) != np.interp(a, ti, ga)
    out[crosses] = np.nan
    return out


def _gyro_white_var(ti: np.ndarray, gz: np.ndarray, gap: np.ndarray, density: float) -> float:
    """The gyro's white noise variance per sample: from its own second differences (``6 sigma^2`` for white noise;
    the motion is smooth at the IMU's rate), robustly; the configured density's where too few samples."""
    ok = ~(gap[1:] | gap[:-1])
    if np.count_nonzero(ok) < MIN_SAMPLES:
        return density**2 / float(np.median(np.diff(ti)))
    return white_variance(gz, ok)


def weigh(tw_ns: np.ndarray, yaw: np.ndarray, ti_ns: np.ndarray, gz: np.ndarray, imu_gap_ns: int,
          gyro_density: float, gate_z: float, speed: np.ndarray | None = None
          ) -> tuple[YawCheck, np.ndarray | None, np.ndarray | None]:
    """The check (module docstring): (report, the wheel yaw rates with far and unchecked samples NaN, their
    variances), the two arrays None where the wheels' yaw rate stays out. ``speed``: the wheels' forward speed
    at their stamps (a yaw rate that follows it, unequal radii, leaves the wheels out)."""
    rep = YawCheck()
    t0 = int(ti_ns[0])
    tw, ti = (tw_ns - t0) * 1e-9, (ti_ns - t0) * 1e-9
    gap = np.diff(ti_ns) > imu_gap_ns if imu_gap_ns > 0 else np.zeros(len(ti) - 1, bool)
    ok = np.isfinite(yaw)
    if ok.sum() < MIN_SAMPLES or np.ptp(tw[ok]) < MIN_SPAN_S:
        rep.why = f"fewer than {MIN_SAMPLES} wheel yaw rates over {MIN_SPAN_S:g} s: the gyro's alone"
        return rep, None, None
    period = float(np.median(np.diff(tw[ok])))
    win = max(period, ACCEL_WINDOW_S)
    g = _gyro_mean(ti, gz, gap, tw - 0.5 * period, tw + 0.5 * period)
    ok &= np.isfinite(g)
    if ok.sum() < MIN_SAMPLES or np.abs(g[ok]).max() < MIN_YAW_RATE_RADPS:
        rep.why = f"the drive never turns faster than {MIN_YAW_RATE_RADPS:g} rad/s: the wheels' yaw scale is not seen"
        return rep, None, None
    idx = np.flatnonzero(ok)
    chunk = np.floor(tw[idx] / CHUNK_S).astype(np.int64)
    _, inv = np.unique(chunk, return_inverse=True)
    tc = tw[idx] / CHUNK_S - chunk - 0.5  # each chunk's own time, centred: the normal equations stay well conditioned
    d = g[idx] - yaw[idx]
    fit = Fit.of(tw[idx], inv, tc, g[idx], d)
    r, sigma, n, c, c_sigma = fit.r, fit.sigma, int(fit.keep.sum()), fit.c, fit.c_sigma
    follows = False
    if speed is not None:
        rep.speed_share, rep.speed_share_sigma, share_radps = speed_share(inv, np.asarray(speed, float)[idx], fit)
        # a share that matters: beyond its noise, and turning more than the scale's tolerance on the yaw rate would
        follows = abs(rep.speed_share) > SPEED_SHARE_Z * rep.speed_share_sigma \
            and share_radps > SCALE_TOL * float(np.sqrt(np.mean(g[idx][fit.keep] ** 2)))
    gyro_var = _gyro_white_var(ti, gz, gap, gyro_density) * float(np.median(np.diff(ti))) / period
    wheel_var = max(sigma**2 - gyro_var, RESOLVE_Z * sigma**2 * np.sqrt(2.0 / n))
    accel = (_gyro_mean(ti, gz, gap, tw, tw + win) - _gyro_mean(ti, gz, gap, tw - win, tw)) / win
    floor2 = gyro_var + (np.nan_to_num(accel[idx]) * 0.5 * period) ** 2  # what the comparison cannot resolve
    far = np.zeros(len(yaw), bool)
    far[idx] = np.abs(r) > gate_z * np.maximum(max(sigma, 1e-12), np.sqrt(floor2))
    rep.scale_off, rep.scale_off_sigma, rep.residual_sigma_radps = c, c_sigma, sigma
    rep.sigma_radps = float(np.sqrt(wheel_var))
    rep.far = int(far.sum())
    if follows:
        rep.why = (f"the wheels' yaw rate follows their speed ({-rep.speed_share:+.2g} +- {rep.speed_share_sigma:.1g} "
                   "rad/m: unequal radii), which a scale does not hold: the gyro's alone" + _in_degrees(1.0 - c))
        return rep, None, None
    if abs(c) > MAX_SCALE_OFF:
        rep.why = (f"the wheels' yaw rate is {-c:+.1%} off the gyro's scale, beyond {MAX_SCALE_OFF:.0%}: not a "
                   "radius or baseline error (a zero, flipped or skid-steered yaw rate): the gyro's alone"
                   + _in_degrees(1.0 - c))
        return rep, None, None
    if 2.0 * c_sigma > SCALE_TOL:
        rep.why = (f"the wheels' yaw scale is {-c:+.2%} +- {c_sigma:.3%} off the gyro's, not measured to "
                   f"{SCALE_TOL:.1%}: the gyro's alone")
        return rep, None, None
    if rep.far > MAX_FAR_SHARE * len(idx):
        rep.why = (f"{rep.far} of {len(idx)} wheel yaw rates are further than the gate from the gyro's (more than "
                   f"{MAX_FAR_SHARE:.0%}): the gyro's alone")
        return rep, None, None
    if rep.far:  # a run of far samples (a slip) widens to its edges; a lone one is left out alone
        far = widened(tw, far, SLIP_EDGE_S) & np.isfinite(yaw)
        rep.far = int(far.sum())
    unchecked = np.isfinite(yaw) & ~np.isfinite(g) & ~far
    rep.unchecked = int(unchecked.sum())
    rep.scale_applied = abs(c) > RESOLVED_Z * c_sigma
    k = 1.0 - c if rep.scale_applied else 1.0  # the wheels' yaw scale: wheel = k gyro - bias
    out = yaw / k
    out[far | unchecked] = np.nan
    share = c_sigma if rep.scale_applied else abs(c) + c_sigma
    var = (wheel_var + (share * np.nan_to_num(yaw)) ** 2) / k**2
    rep.used, rep.far_mask, rep.unchecked_mask = True, far, unchecked
    rep.why = (f"the wheels' yaw rate agrees with the gyro's ({-c:+.3%} +- {c_sigma:.3%} scale"
               + (", divided out" if rep.scale_applied else "") + "; noise "
               f"{rep.sigma_radps:.2g} rad/s from the residual): used beside it"
               + (f", {rep.far} sample{'s' * (rep.far != 1)} of slips left out" if rep.far else "")
               + unchecked_clause(rep.unchecked))
    return rep, out, var


def unchecked_clause(unchecked: int, bridging: int = 0) -> str:
    """The check's words for its ``unchecked`` yaw rates, ``bridging`` of them used across the gyro's gaps after
    all (``gyro_gaps``)."""
    left = unchecked - bridging
    return ((f", {bridging} bridging the gyro's gaps" if bridging else "")
            + (f", {left} without the gyro left out" if left > 0 else ""))
