"""Wheel increments beside odometry: the wheels' speed scale found, slips left out.

Wheels read their forward speed times a scale (a radius off by a few percent) plus slips (bursts of 20-30 % for
a second or two); beside odometry both are observable. A pre-pass compares the wheel increments with the
graph's starting values (the odometry's poses) over windows of ``WINDOW_NS``: the scale is the median ratio over
the windows, and a window whose scaled increment misses the odometry's by more than ``GATE_REL`` of its length
and ``GATE_K`` robust sigmas of every window's miss is a slip: its increments (and ``GATE_DILATE`` windows either
side) are left out of the graph and counted (``Gate.rejected``). The rest say ``R_k^T (p_k+1 - p_k) = s dp_k``
under a Huber loss, ``s`` the pre-pass's, in GTSAM's own between factor (the scale as a graph variable, a Python
factor per increment, landed within 0.06 % of it at 3x the cost: docs/benchmarks.md). ``against_odometry`` is the
same comparison over the whole log before the graph (the height prior's evidence, ``height``).

The wheels' yaw rate, where the timeline let it in beside the gyro (``wheel_yaw``: it agrees with the gyro, its
noise measured, slips out): ``YawTrack``, one factor per keyframe interval whose rotation is the gyro's with the
yaw turned to the wheels' (their yaw increment less the gyro's, bias-corrected at the linearisation point), tight
about z only, Gaussian, the wheels' sigma summed over the interval as the speed's is.
"""

from __future__ import annotations

from dataclasses import dataclass

import gtsam
import numpy as np

from ...robust import robust_sigma

WINDOW_NS = 1_000_000_000  # the pre-pass's windows: a slip lasts one or two, odometry's noise averages within
GATE_REL = 0.05  # a window's miss beyond this share of its length is a slip (bursts are 20-33 %)
GATE_K = 3.0  # and beyond this many robust sigmas of the windows' misses (odometry's own noise at low speed)
GATE_DILATE = 1  # windows left out on each side of a slip's
MIN_WINDOW_M = 0.05  # windows shorter than this do not vote for the scale
SCALE_BOUNDS = (0.5, 2.0)  # a pre-pass scale outside these is not a wheel's: 1 is kept
ODOM_SCALE_OFF = 0.2  # the odometry's path off the wheels' distance by more: its units or scale, told
AGREE_SIGMAS = 3.0  # the wheels agree with the odometry where their ratio is within this many standard errors of 1
MIN_SIGMA_M = 0.001  # a short interval's (a fix beside an odometry pose) increment is no surer than the poses
# the increments' sigmas times this (as without the scale, ``factors.ODOM_WHEEL_SIGMA_SCALE``): tighter, the
# rover's wheels drew the graph off beside odometry and GPS, slips gated out or not (docs/benchmarks.md)
SIGMA_SCALE = 30.0
LOOSE_ROTATION_RAD = 1.0  # the fixed-scale factor's rotation: the gyro's (already in the IMU factor)
FREE_M = 1e4  # the yaw factor's translation: free
HUBER_K = 2.0  # whitened norm of a 3D increment residual (what the gate let through at a slip's edges)
SLIP_WHY = ("a keyframe interval's wheel increment, times the wheel scale, missed the odometry's beyond the gate "
            "(a slip): left out of the factor graph")


@dataclass
class Gate:
    """The pre-pass of one chunk: the scale found and the keyframe intervals left out (slips)."""
    scale: float
    rejected: np.ndarray  # keyframe indices k of the intervals [k, k+1] left out


def gate(kt: np.ndarray, states: dict[str, np.ndarray], ks: np.ndarray, dps: np.ndarray) -> Gate:
    """The scale and slips of wheel increments ``dps`` (rows: interval [k, k+1] for k in ``ks``, in base axes of
    k) against the keyframe states' own increments (module docstring)."""
    if not len(ks):
        return Gate(1.0, np.zeros(0, np.int64))
    R, p = states["R"], states["p"]
    a = np.einsum("nji,nj->ni", R[ks], p[ks + 1] - p[ks])
    w = (kt[ks] - kt[0]) // WINDOW_NS
    _, inv = np.unique(w, return_inverse=True)
    A = np.stack([np.bincount(inv, a[:, c]) for c in range(3)], 1)
    D = np.stack([np.bincount(inv, dps[:, c]) for c in range(3)], 1)
    length = np.linalg.norm(D, axis=1)
    moving = length > MIN_WINDOW_M
    scale = 1.0
    if moving.any():
        s = float(np.median(np.einsum("ni,ni->n", A[moving], D[moving]) / length[moving] ** 2))
        scale = s if SCALE_BOUNDS[0] <= s <= SCALE_BOUNDS[1] else 1.0
    miss = np.linalg.norm(A - scale * D, axis=1)
    robust = robust_sigma(miss, centre=False)
    slip = (miss > GATE_REL * scale * length) & (miss > GATE_K * robust)
    for _ in range(GATE_DILATE):  # a slip's edges (its onset and end) in the neighbouring windows
        slip[1:] |= slip[:-1].copy()
        slip[:-1] |= np.r_[slip[1:]]
    return Gate(scale, ks[slip[inv]])


class YawTrack:
    """The wheels' yaw rate and sigma held over each IMU segment from the message nearest its middle; ``ok`` where
    one lies within a wheel gap of it."""

    def __init__(self, z: np.ndarray, sigma: np.ndarray, ok: np.ndarray):
        self.z, self.sigma, self.ok = z, sigma, ok

    @classmethod
    def of(cls, prep, seg_t: np.ndarray, seg_dt: np.ndarray, nearest) -> YawTrack | None:
        w = prep.wheel
        if w is None or len(w) < 2 or "yaw_rate" not in prep.use.get("wheel", ()) or w.yaw_rate_var is None:
            return None
        has = np.isfinite(w.yaw_rate_radps)
        period = float(np.median(np.diff(w.stamps_ns))) * 1e-9
        mid = seg_t + (0.5e9 * seg_dt).astype(np.int64)
        j = nearest(w.stamps_ns, mid)
        ok = has[j] & (np.abs(w.stamps_ns[j] - mid) <= max(1.5 * period * 1e9, 2.5e7))
        return cls(np.nan_to_num(w.yaw_rate_radps[j]), np.sqrt(w.yaw_rate_var[j]), ok)

    def factor(self, ka, kb, dR: gtsam.Rot3, gyro_z: np.ndarray, bias_z: float, dt: np.ndarray,
               segs: slice, loose: float = 1.0) -> gtsam.BetweenFactorPose3:
        """The interval's rotation with the wheels' yaw (class docstring), its sigma times ``loose``; its
        translation free."""
        turn = float(np.dot(self.z[segs] - (gyro_z[segs] - bias_z), dt[segs]))
        sz = loose * float(np.dot(self.sigma[segs], dt[segs]))
        sig = np.r_[LOOSE_ROTATION_RAD, LOOSE_ROTATION_RAD, max(sz, 1e-9),
                    np.full(3, FREE_M)]
        meas = gtsam.Pose3(dR.compose(gtsam.Rot3.Rz(turn)), np.zeros(3))
        return gtsam.BetweenFactorPose3(ka, kb, meas, gtsam.noiseModel.Diagonal.Sigmas(sig))


def fixed_scale_factor(ka, kb, dR: gtsam.Rot3, dp: np.ndarray, sd: np.ndarray) -> gtsam.BetweenFactorPose3:
    """The robust wheel increment ``dp`` (already scaled) as GTSAM's own between factor, its rotation the gyro's
    ``dR``, loose."""
    loss = gtsam.noiseModel.mEstimator.Huber.Create(HUBER_K)
    sig = np.r_[np.full(3, LOOSE_ROTATION_RAD), np.maximum(SIGMA_SCALE * sd, MIN_SIGMA_M)]
    model = gtsam.noiseModel.Robust.Create(loss, gtsam.noiseModel.Diagonal.Sigmas(sig))
    return gtsam.BetweenFactorPose3(ka, kb, gtsam.Pose3(dR, np.asarray(dp, float)), model)


@dataclass
class Spans:
    """The wheels against the odometry over the whole log: the scale and the spans that slipped."""
    scale: float
    slips_ns: np.ndarray  # (n, 2) start, end of each window found slipping


def _windows(wheel, odom) -> tuple[np.ndarray, np.ndarray, np.ndarray] | None:
    """Window edges, the odometry's forward path and the wheels' distance over each ``WINDOW_NS``, or None."""
    t0, t1 = max(wheel.stamps_ns[0], odom.stamps_ns[0]), min(wheel.stamps_ns[-1], odom.stamps_ns[-1])
    edges = np.arange(t0, t1 + 1, WINDOW_NS)
    if len(edges) < 2:
        return None
    P = odom.poses
    # the odometry's forward distance: each increment in its first pose's axes (its noise sideways and vertical
    # would lengthen a path of norms at low speed)
    fwd = np.einsum("ni,ni->n", P[:-1, :3, 0], np.diff(P[:, :3, 3], axis=0))
    path = np.r_[0.0, np.cumsum(fwd)]
    speed = np.nan_to_num(wheel.velocity_mps[:, 0])
    dist = np.r_[0.0, np.cumsum(0.5 * (speed[1:] + speed[:-1]) * np.diff(wheel.stamps_ns) * 1e-9)]
    return edges, np.diff(np.interp(edges, odom.stamps_ns, path)), np.diff(np.interp(edges, wheel.stamps_ns, dist))


def _ratio(a: np.ndarray, d: np.ndarray) -> float | None:
    moving = np.abs(d) > MIN_WINDOW_M
    return float(np.median(a[moving] / d[moving])) if moving.any() else None


def odometry_scale_note(wheel, odom) -> str | None:
    """A note where the odometry's path is further from the wheels' distance than a wheel's radius error: its
    units or scale are likely off (a millimetre written as a metre), and the fused trajectory follows it."""
    if wheel is None or odom is None or len(wheel) < 2 or len(odom) < 2:
        return None
    found = _windows(wheel, odom)
    s = None if found is None else _ratio(found[1], found[2])
    if s is None or abs(s - 1.0) <= ODOM_SCALE_OFF:
        return None
    if s < 0:  # the odometry goes forward where the wheels turn backwards: a sign, not a scale
        return (f"odometry: its path runs against the wheels' speed ({s:.4g}x their distance): the wheels' speed "
                "has its sign reversed, or the odometry's forward axis is not the base's")
    return (f"odometry: its path is {s:.4g}x the wheels' distance, beyond a wheel's radius error "
            f"({ODOM_SCALE_OFF:.0%}): check its units and scale (the fused trajectory follows it)")


def odometry_agreement(wheel, odom) -> tuple[bool, str]:
    """Whether the wheels' distance agrees with the odometry's path, and why: no window slipped (``against_odometry``)
    and their ratio, the median over the moving windows, within ``AGREE_SIGMAS`` of its standard error of 1 (the
    data cannot then tell which of the two is off)."""
    found = None if wheel is None or odom is None or len(wheel) < 2 or len(odom) < 2 else _windows(wheel, odom)
    moving = np.abs(found[2]) > MIN_WINDOW_M if found is not None else np.zeros(0, bool)
    if moving.sum() < 5:
        return False, "too little motion to weigh the wheels against the odometry"
    slips = len(_spans(*found).slips_ns)
    if slips:
        return False, f"the wheels slip against the odometry ({slips} {WINDOW_NS / 1e9:g} s windows)"
    r = found[1][moving] / found[2][moving]
    s, se = float(np.median(r)), 1.25 * robust_sigma(r) / np.sqrt(moving.sum())  # a median's standard error
    said = f"the odometry's path {s:.4f}x the wheels' distance (+- {se:.4f})"
    return abs(s - 1.0) <= AGREE_SIGMAS * se, said


def against_odometry(wheel, odom) -> Spans:
    """The wheels' distance per ``WINDOW_NS`` against the odometry's path over it: the scale (median ratio of
    the moving windows) and the slips (the gate of ``gate``), without the graph's states (the height prior's
    evidence needs them before the graph is built)."""
    found = _windows(wheel, odom)
    return Spans(1.0, np.zeros((0, 2), np.int64)) if found is None else _spans(*found)


def _spans(edges: np.ndarray, a: np.ndarray, d: np.ndarray) -> Spans:
    """``against_odometry`` on its windows (edges, the odometry's path and the wheels' distance over each)."""
    moving = np.abs(d) > MIN_WINDOW_M
    s = _ratio(a, d)
    scale = s if s is not None and SCALE_BOUNDS[0] <= s <= SCALE_BOUNDS[1] else 1.0
    miss = np.abs(a - scale * d)
    slip = moving & (miss > GATE_REL * scale * np.abs(d)) & (miss > GATE_K * robust_sigma(miss, centre=False))
    return Spans(scale, np.column_stack([edges[:-1][slip], edges[1:][slip]]))
