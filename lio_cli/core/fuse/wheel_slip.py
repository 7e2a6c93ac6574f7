"""Wheel slip and wheel scale from the accelerometer, before the planar or 3D filter (IMU + wheel speed, no odometry).

A slip (wet grass, gravel, a spinning wheel) makes the wheel speed jump by a share of itself in a fraction of a
second while the accelerometer feels no such acceleration. ``tilt_track.forward_accel`` gives the forward
acceleration the IMU feels: the specific force plus gravity's forward share, the gravity direction in the base
frame anchored from the accelerometer at the start of each ``tilt_track.SEGMENT_S`` stretch (a log under two: its
first second) and carried by the gyro alone within it (pitch on uneven ground is taken out; the wheels never pull
it, their scale is what it measures; the gyro's bias walk never tilts it for longer than a stretch). Its integral
is a speed track; the wheel speed times the scale minus that track is flat but for the accelerometer's forward
bias, each stretch's gyro x/y bias and anchor tilt (a ramp and slow curves of known shape), and a slip's jump.
The body frame's own rotation is taken out first: ``dv_x/dt = a_x - w_y v_z``, the pitch rate times the heave's
rate (``_heave_coupling``; a rover bouncing over 300 s read exact wheels 2 % slow without it).

``_fit_scale``: the wheel scale ``s`` (``s * wheel = true speed``) and those terms by least squares on the
speed increments over ``BLOCK_S`` outside slips (blocks left far off trimmed; combinations of the terms the drive
never shows, as on a straight one, left out). The scale's sigma holds, besides the fit's residual, the gyro's angle
random walk: its white noise (measured from the data) walks the carried gravity direction from each anchor, an
error the constant-bias terms cannot take out and the blocks share (``tilt_track.walk_variance``). Slips:
``slip_windows`` (a jump of the difference until it is back at its level). The first fit leaves out the raw
difference's jumps (``slip_windows.guard``); fit and detection then alternate ``FIT_PASSES`` times. The mount's
pitch (the log's median up direction, ``tilt_track.mount_cosine``: a start on a slope is the ground's, not the
mount's) divides the forward acceleration by its cosine.

The scale is applied where it is measured (the fit's own sigma, from its residual, at most ``MAX_SCALE_SIGMA``, or
``LOOSE_SCALE_SIGMA`` for a scale off 1 by a few percent) and off 1 by more than ``SCALE_Z`` sigmas of its whole
uncertainty, the angle random walk's share included; a calibration that scaled the wheels (``speed_scale_sigma``)
is weighed in. Slips are bridged (their wheel speeds replaced by the IMU's speed, integrated from both ends of the
window and blended) only when the scale is measured or applied (the wheels are ``verified`` only where it is known
to ``MAX_SCALE_SIGMA``): a slip's extra distance is a share of the path as a scale error's is, and removing the
slips alone made every simulated bad-wheel track worse (docs/benchmarks.md). A slip longer than ``MAX_SLIP_S`` is
kept out of the fit whole but bridged only when the IMU's speed integrated across it lands on the wheel speed after
it (``_closes``); otherwise it is left in and counted (``left_in``).
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace

import numpy as np

from ..imu import running_integral
from ..robust import robust_sigma
from . import heave
from .kalman import chi2_thresholds
from .slip_windows import DRIFT_S, EDGE_S, JUMP_S, SIGMA_FLOOR_MPS, detect, guard, running_median
from .timeline import Prepared
from .tilt_track import StretchIntegral, angle_walk_q, forward_accel, walk_variance

MAX_SLIP_S = 5.0  # a slip longer than this is kept out of the fit, bridged only if the IMU's speed closes it
CLOSE_REL = 0.05  # ... within this share of the speed (or CLOSE_MPS) of the wheel speed after it
CLOSE_MPS = 0.05
BLOCK_S = 1.0  # speed increments over this long fit the scale and bias
MAX_SCALE_SIGMA = 0.005  # a scale known no better than this leaves the wheels as they are ...
LOOSE_SCALE_SIGMA = 0.01  # ... unless known to this and off 1 by SCALE_Z sigmas
MIN_CALIBRATION_SIGMA = 0.001  # a calibration's scale is trusted no further (a sigma of 0 is a claim, not a fact)
SCALE_Z = 3.0  # sigmas off 1 before the scale is applied
MAX_SCALE_OFF = 0.2  # a fitted scale further from 1 than this says the IMU's axes are wrong, not the wheels
MIN_SPAN_S = 10.0  # shorter logs: nothing is estimated
FIT_PASSES = 3  # fit then detect, this many times
TRIM_PASSES = 2  # blocks further than TRIM_Z robust sigmas from the fit are left out, this many times
TRIM_Z = 4.0
MIN_BLOCKS = 12  # fewer clean increments: no fit
MAX_LAG_S, MIN_LAG_S = 1.0, 0.1  # an IMU clock offset is looked for within this and reported from that
LAG_CORR, LAG_CORR_GAIN = 0.7, 0.15  # ... when the shifted speed changes correlate this well, this much better
RCOND = 1e-5  # singular values of the fit's (column-normalised) matrix below this share of the largest: unseen


@dataclass
class SlipReport:
    """What the check found (in the metrics as ``wheel_check``)."""

    windows: list[tuple[float, float]] = field(default_factory=list)  # seconds from the first wheel stamp
    scale: float | None = None
    scale_sigma: float | None = None
    scale_applied: bool = False
    bridged: int = 0
    left_in: int = 0  # slips longer than MAX_SLIP_S the IMU's speed did not close: out of the fit, not bridged
    verified: bool = False  # the scale measured, near 1, every slip bridged: the speeds can be trusted
    why: str = ""
    measured: bool = False  # the fit knew the scale (MAX_SCALE_SIGMA) and found it near 1 (MAX_SCALE_OFF)

    def to_dict(self) -> dict:
        return {"slips": len(self.windows), "windows_s": [[round(a, 2), round(b, 2)] for a, b in self.windows],
                "scale": None if self.scale is None else round(self.scale, 4),
                "scale_sigma": None if self.scale_sigma is None else round(self.scale_sigma, 4),
                "scale_applied": self.scale_applied, "bridged": self.bridged, "left_in": self.left_in,
                "measured": self.measured, "verified": self.verified, "why": self.why}


def applies(prep: Prepared) -> bool:
    """IMU gyro and accelerometer plus a forward wheel speed, long enough to measure."""
    w, imu = prep.wheel, prep.imu
    if w is None or imu is None or prep.imu_f_b is None or len(w) < 10 or len(imu) < 10:
        return False
    if not {"gyro", "accel"} <= set(prep.use.get("imu", ())) or "speed" not in prep.use.get("wheel", ()):
        return False
    return (w.stamps_ns[-1] - w.stamps_ns[0]) * 1e-9 >= MIN_SPAN_S and np.isfinite(w.velocity_mps[:, 0]).sum() >= 10


def _integral_at(t: np.ndarray, t_s: np.ndarray, x: np.ndarray, gap: np.ndarray) -> np.ndarray:
    """The running trapezoid integral of ``x`` (sampled at ``t_s``) at the stamps ``t``; steps across an IMU
    gap (``gap``, one per step) add nothing."""
    X = running_integral(t_s, x, gap)
    if x.ndim == 1:
        return np.interp(t, t_s, X)
    return np.column_stack([np.interp(t, t_s, X[:, j]) for j in range(x.shape[1])])


def _fit_scale(t: np.ndarray, v: np.ndarray, A: np.ndarray, G: np.ndarray | StretchIntegral, clean: np.ndarray,
               walk_q: float, anchors: np.ndarray) -> tuple[float, float, float, np.ndarray] | str:
    """(scale, its sigma from the residual, its sigma from the angle walk, c) of ``s * dv = dA - c0 dt - dG
    c[1:]`` over ``BLOCK_S`` increments inside clean stretches: ``c0`` the accelerometer's forward bias,
    ``c[1:]`` the gyro's x, y bias and the start's tilt error (``G``: their effect on the integrated
    acceleration, ``forward_accel``); or why not. Combinations of the terms the drive leaves unseen (a straight
    one: the roll tilt and gyro x bias) are left out (``RCOND``). ``walk_q`` ((m/s^2)^2/s): the forward
    acceleration's random walk from the carried gravity direction (``walk_variance``), restarted at each of
    ``anchors``; ``t`` and ``anchors`` count from the first IMU stamp."""
    rows, spans = [], []
    k = 0
    while k < len(t) - 1:
        j = int(np.searchsorted(t, t[k] + BLOCK_S))
        if j >= len(t):
            break
        if clean[k:j + 1].all():
            rows.append(np.concatenate([[v[j] - v[k], t[j] - t[k]], G[j] - G[k], [A[j] - A[k]]]))
            spans.append((t[k], t[j]))
            k = j
        else:
            k += 1
    few = (f"{len(rows)} clean {BLOCK_S:g} s stretches (no slip window, no IMU gap), fewer than {MIN_BLOCKS}: "
           "scale not measured")
    if len(rows) < MIN_BLOCKS:
        return few
    M = np.array(rows)
    if np.abs(M[:, 0]).max() < SIGMA_FLOOR_MPS:
        return "the wheel speed never changed enough to measure its scale against the accelerometer"
    keep = np.ones(len(M), bool)
    for _ in range(TRIM_PASSES + 1):  # blocks a slip the windows missed are trimmed, then the fit redone
        fitted = keep
        X, y = M[keep, :-1], M[keep, -1]
        if len(y) < MIN_BLOCKS:
            return (f"{len(M) - len(y)} of {len(M)} speed increments disagree with the accelerometer's beyond "
                    f"{TRIM_Z:g} sigmas: the IMU's forward axis is likely not the base's, scale not measured")
        norm = np.maximum(np.abs(X).max(axis=0), 1e-12)
        U, S, Vt = np.linalg.svd(X / norm, full_matrices=False)
        seen = S > RCOND * S[0]
        if np.abs(Vt[~seen, 0]).max(initial=0.0) > 0.1:
            return ("the wheel speed's changes cannot be told from the accelerometer's bias and tilt terms "
                    "(ill-conditioned fit): scale not measured")
        P = Vt[seen].T / S[seen]  # the truncated pseudo-inverse is P U^T, its covariance P P^T
        sol = P @ (U[:, seen].T @ y) / norm
        r_all = M[:, -1] - M[:, :-1] @ sol
        r = r_all[keep]
        mad = robust_sigma(r)
        keep = np.abs(r_all - np.median(r)) <= TRIM_Z * max(mad, 1e-9)
    s2 = float(r @ r) / max(len(r) - int(seen.sum()), 1)
    cov = s2 * (P @ P.T) / np.outer(norm, norm)
    a = U[:, seen] @ P[0] / norm[0]  # the scale as a weighted sum of the kept blocks' dA
    walk = walk_q * float(a @ walk_variance(np.array(spans)[fitted], anchors) @ a) if walk_q else 0.0
    return float(sol[0]), float(np.sqrt(cov[0, 0])), float(np.sqrt(walk)), sol[1:]


def _heave_coupling(prep: Prepared, t: np.ndarray) -> np.ndarray | float:
    """What the base's heave adds to the forward acceleration the IMU feels, at its stamps (seconds ``t``): in the
    body frame ``dv_x/dt = a_x - w_y v_z``, and a robot bouncing on uneven ground (``v_z`` the heave's rate,
    ``heave.heights``, from the accelerometer alone: the wheels it checks may slip) while it pitches turns that
    product into a slow drift the scale fit takes for the wheels'."""
    z = heave.heights(prep, prep.imu.stamps_ns, wheels=False)
    if z is None:
        return 0.0
    with np.errstate(divide="ignore", invalid="ignore"):
        return np.nan_to_num(prep.imu_w_b[:, 1] * np.gradient(z, t))


def check_wheels(prep: Prepared, gate_probability: float, gravity_mps2: float, walk: bool = True) -> SlipReport:
    """Find slips and the wheel scale; replace ``prep.wheel`` by the corrected copy where they are measured
    (module docstring). Counts ``slip_bridged`` / ``slip_left_in`` / ``scale_corrected`` notes. ``walk``: the angle
    walk's share of the scale's sigma (False: left out, for a trial asking only whether it is ``measured``)."""
    rep = SlipReport()
    w, imu = prep.wheel, prep.imu
    ok = np.isfinite(w.velocity_mps[:, 0])
    tw_ns = w.stamps_ns[ok]
    t0 = tw_ns[0]
    tw = (tw_ns - t0) * 1e-9
    vw = w.velocity_mps[ok, 0]
    ti = (imu.stamps_ns - t0) * 1e-9
    gap = np.diff(imu.stamps_ns) > prep.imu_gap_ns if prep.imu_gap_ns > 0 else np.zeros(len(ti) - 1, bool)
    a, sens, starts = forward_accel(ti, prep.imu_f_b, prep.imu_w_b, tw, vw, gravity_mps2, gap)
    a = a - _heave_coupling(prep, ti)
    anchors = ti[starts] - ti[0]
    A = _integral_at(tw, ti, a, gap)
    # one stretch: its four columns; more: kept per stretch (their matrix grows with the log's length squared)
    G = _integral_at(tw, ti, sens, gap) if len(starts) == 1 else StretchIntegral(tw, ti, sens, starts, gap)
    # the pitch the gyro carries walks with its y axis's white noise: g times that walk is the acceleration's
    walk_q = gravity_mps2**2 * angle_walk_q(ti, prep.imu_w_b[:, 1]) if walk else 0.0
    inside = (tw >= ti[0]) & (tw <= ti[-1])
    for k in np.flatnonzero(gap):  # the IMU's speed is unknown across its gaps: no slip test or fit there
        inside &= (tw < ti[k]) | (tw > ti[k + 1] + JUMP_S)
    z = float(np.sqrt(chi2_thresholds(gate_probability, 1)[1]))  # inf without a gate: no slip
    wins, plain = guard(tw, vw - A, vw, inside, z)  # first around every jump of the raw IMU speed
    fit: tuple | str = ""
    for p in range(FIT_PASSES):
        fit = _fit_scale(tw - ti[0], vw, A, G, _clean(inside, wins), walk_q, anchors)
        if isinstance(fit, str) and p == 0 and wins != plain:  # departures kept out left too little: the jumps alone
            wins = plain
            fit = _fit_scale(tw - ti[0], vw, A, G, _clean(inside, wins), walk_q, anchors)
        if isinstance(fit, str):
            break
        s, s_fit, s_walk, c = fit
        wins = detect(tw, s * vw - (A - c[0] * tw - G @ c[1:]), vw, inside, z)
    if isinstance(fit, str):  # no windows reported: none were used
        rep.why = fit + _clock_hint(tw, vw, A, inside)
        return rep
    clean = _clean(inside, wins)
    rep.windows = [(float(tw[i]), float(tw[j])) for i, j in wins]
    A = A - c[0] * tw - G @ c[1:]
    s_sigma = float(np.hypot(s_fit, s_walk))
    if w.speed_scale_sigma is not None:  # a calibration scaled the wheels: its scale, 1 now, weighed in
        s, s_fit, s_sigma = _with_calibration(s, s_fit, s_sigma, w.speed_scale_sigma)
    rep.scale, rep.scale_sigma = s, s_sigma
    # known only to LOOSE_SCALE_SIGMA, a scale far enough off 1 is still applied: its error is then a third of
    # the wheels' (not ``measured``: the estimator choice asks for MAX_SCALE_SIGMA)
    loose = MAX_SCALE_SIGMA < s_fit <= LOOSE_SCALE_SIGMA and abs(s - 1.0) > SCALE_Z * s_sigma
    if s_fit > MAX_SCALE_SIGMA and not loose:
        rep.why = (f"wheel scale {s:.4f} +- {s_fit:.4f} (the fit's): not measured by the accelerometer to "
                   f"{MAX_SCALE_SIGMA:.1%} (the speed changes too little, or the IMU's axes are off), so {len(wins)} "
                   "slip(s) left in") + _clock_hint(tw, vw, A, inside)
        return rep
    if abs(s - 1.0) > MAX_SCALE_OFF:
        rep.why = (f"wheel scale {s:.4f}: further from 1 than a wheel's radius error ({MAX_SCALE_OFF:.0%}), the "
                   f"IMU's forward axis is likely not the base's"
                   + (" or the wheels' speed has its sign reversed" if s < 0 else "") + ": wheels left as they are")
        return rep
    rep.measured = not loose
    rep.scale_applied = bool(abs(s - 1.0) > SCALE_Z * s_sigma)
    scale = s if rep.scale_applied else 1.0
    v_new = scale * vw
    n_bridged = n_left = 0
    for i, j in wins:
        if tw[j] - tw[i] > MAX_SLIP_S + 2 * EDGE_S and not _closes(i, j, scale * vw, A, clean):
            rep.left_in += 1
            n_left += j - i + 1
            continue
        v_new[i:j + 1] = _bridge(i, j, tw, scale * vw, A, clean)
        n_bridged += j - i + 1
    rep.bridged = n_bridged
    rep.verified = rep.left_in == 0 and not loose  # trusted where the scale is known to MAX_SCALE_SIGMA
    vel = w.velocity_mps.copy()
    vel[ok, 0] = v_new
    var = None
    if w.velocity_var is not None:
        var = w.velocity_var.copy()
        var[ok, 0] *= scale**2
    prep.wheel = replace(w, velocity_mps=vel, velocity_var=var)
    report = prep.reports["wheel"]
    report.note("slip_bridged", n_bridged)  # replaced, not dropped: no rejection
    report.note("slip_left_in", n_left)
    if rep.scale_applied:
        report.note("scale_corrected", int(ok.sum()))
    how = ["applied" if rep.scale_applied else "taken as 1"] + [f"known to {LOOSE_SCALE_SIGMA:.0%} only"] * loose \
        + ["with the calibration's"] * (w.speed_scale_sigma is not None)
    rep.why = (f"wheel scale {s:.4f} +- {s_sigma:.4f} ({', '.join(how)}); "
               f"{len(wins) - rep.left_in} slip(s) bridged by the IMU"
               + (f", {rep.left_in} longer than {MAX_SLIP_S:g} s left in (out of the scale fit)" * bool(rep.left_in)))
    return rep


def _with_calibration(s: float, s_fit: float, s_sigma: float, cal_sigma: float) -> tuple[float, float, float]:
    """The fitted scale and its sigmas (the fit's, the whole) beside a calibration's: 1 (it scaled the wheels
    already) within ``cal_sigma``, at least ``MIN_CALIBRATION_SIGMA``; inverse-variance weighted."""
    c = max(cal_sigma, MIN_CALIBRATION_SIGMA)
    k = c**2 / (c**2 + s_sigma**2)  # the fit's share
    shrink = float(np.sqrt(k))
    return 1.0 + k * (s - 1.0), s_fit * shrink, s_sigma * shrink


def _clock_hint(t: np.ndarray, v: np.ndarray, A: np.ndarray, inside: np.ndarray) -> str:
    """A hint when the wheel speed's 1 s changes match the IMU speed track's (``A``; both less their running
    median, a tilt's drift) far better with the IMU stamps shifted (by ``MIN_LAG_S`` to ``MAX_LAG_S``): an IMU
    clock offset spoils the check."""
    keep = inside & (t >= t[0] + MAX_LAG_S + 0.5) & (t <= t[-1] - MAX_LAG_S - 0.5)
    if keep.sum() < 10:
        return ""
    tk = t[keep]

    def change(x: np.ndarray, lag: float) -> np.ndarray:
        d = np.interp(tk + lag + 0.5, t, x) - np.interp(tk + lag - 0.5, t, x)
        return d - running_median(tk, d, DRIFT_S)

    lags = np.round(np.arange(-MAX_LAG_S, MAX_LAG_S + 1e-9, 0.02), 2)
    dv = change(v, 0.0)
    if np.ptp(dv) < SIGMA_FLOOR_MPS:  # a speed that never changes matches nothing
        return ""
    with np.errstate(invalid="ignore", divide="ignore"):  # a flat IMU track: no correlation, taken as none
        corr = np.nan_to_num([np.corrcoef(dv, change(A, lag))[0, 1] for lag in lags], nan=0.0)
    k, k0 = int(np.argmax(corr)), len(lags) // 2
    if abs(lags[k]) < MIN_LAG_S or corr[k] < LAG_CORR or corr[k] - corr[k0] < LAG_CORR_GAIN:
        return ""
    return (f"; the wheel speed's changes match the accelerometer's {lags[k]:+.2f} s later in its stamps "
            f"(correlation {corr[k]:.2f}, {corr[k0]:.2f} unshifted): a clock offset? Try --imu-time-offset "
            f"{-lags[k]:.2f} if the IMU is off, --time-offset wheel={lags[k]:.2f} if the wheels are")


def _clean(inside: np.ndarray, wins: list[tuple[int, int]]) -> np.ndarray:
    clean = inside.copy()
    for i, j in wins:
        clean[i:j + 1] = False
    return clean


def _bridge(i: int, j: int, t: np.ndarray, v: np.ndarray, A: np.ndarray, clean: np.ndarray) -> np.ndarray:
    """Speeds over samples i..j: the IMU's speed from the clean sample before and the one after, blended
    linearly in time (one side alone at the log's ends)."""
    seg = slice(i, j + 1)
    fwd = bwd = None
    if i > 0 and clean[i - 1]:
        k = i - 1
        fwd = v[k] + (A[seg] - A[k])
    if j + 1 < len(t) and clean[j + 1]:
        k = j + 1
        bwd = v[k] - (A[k] - A[seg])
    if fwd is None and bwd is None:
        return v[seg]
    if fwd is None:
        return bwd
    if bwd is None:
        return fwd
    wgt = (t[seg] - t[i - 1]) / max(t[j + 1] - t[i - 1], 1e-9)
    return (1.0 - wgt) * fwd + wgt * bwd


def _closes(i: int, j: int, v: np.ndarray, A: np.ndarray, clean: np.ndarray) -> bool:
    """Whether the IMU's speed from the clean sample before the window lands on the wheel speed of the clean
    sample after it (``CLOSE_REL``, ``CLOSE_MPS``): a long bridge is sound only then."""
    if i == 0 or j + 1 >= len(v) or not (clean[i - 1] and clean[j + 1]):
        return False
    miss = abs(v[i - 1] + A[j + 1] - A[i - 1] - v[j + 1])
    return miss <= max(CLOSE_REL * max(abs(v[i - 1]), abs(v[j + 1])), CLOSE_MPS)


