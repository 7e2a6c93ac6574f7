"""Everything the estimators share before they run: cleaned sources, IMU data in the base frame, the span
and coverage of the motion sources, the output stamps and one time-ordered event stream.

Events are (stamp, kind, index) sorted by stamp, then kind (IMU samples first, so a measurement at an IMU
stamp sees the propagated state; outputs last, so they see every update at their instant).
"""

from __future__ import annotations

from bisect import bisect_right
from dataclasses import dataclass, field, replace

import numpy as np

from ...errors import InputError
from .gps_quality import assess_gps, drop_stale
from .gyro_gaps import GyroGaps, find_gyro_gaps, in_gyro_gap
from .kalman import chi2_thresholds
from .inputs import FuseInputs, FuseOptions, GpsSeries, ImuSeries, PoseSeries, WheelSeries, resolve_use
from .lever import imu_in_base
from .report import SourceReport
from .sanitize import clean_gps, clean_imu, clean_odom, clean_wheel, count_gaps, gap_threshold_ns, orientation_to_base
from .wheel_yaw import Weighed
from .wheel_yaw import weigh as weigh_yaw

IMU, WHEEL, ODOM, GPS, OUT = 0, 1, 2, 3, 4
SOURCE_OF_KIND = {IMU: "imu", WHEEL: "wheel", ODOM: "odom", GPS: "gps"}
MOTION_SOURCES = ("imu", "wheel", "odom")


@dataclass
class Prepared:
    use: dict[str, set[str]]
    reports: dict[str, SourceReport]
    imu: ImuSeries | None = None
    imu_w_b: np.ndarray | None = None  # (N,3) base-frame angular rate
    imu_f_b: np.ndarray | None = None  # (N,3) specific force of the base origin, base axes
    imu_R_wb: np.ndarray | None = None  # (N,3,3) the IMU's own orientation as R_world_base
    imu_gap_ns: int = 0
    wheel: WheelSeries | None = None
    odom: PoseSeries | None = None
    gps: GpsSeries | None = None
    coverage: list[tuple[int, int]] = field(default_factory=list)
    out_stamps: np.ndarray = field(default_factory=lambda: np.zeros(0, np.int64))
    out_dropped: int = 0
    times: np.ndarray = field(default_factory=lambda: np.zeros(0, np.int64))
    kinds: np.ndarray = field(default_factory=lambda: np.zeros(0, np.int8))
    index: np.ndarray = field(default_factory=lambda: np.zeros(0, np.int64))
    notes: list[str] = field(default_factory=list)
    wheel_check: dict | None = None  # wheel_slip.SlipReport.to_dict() where the wheels were checked
    wheel_yaw_weighed: Weighed | None = None  # the wheels' yaw rate weighed against the gyro (FuseOptions.wheel_yaw)
    heave_accel: bool = False  # the accelerometer selected, though the planar filter leaves it out (heave.py)
    gyro_gaps: GyroGaps | None = None  # the gyro's gaps inside the coverage, where it has any
    rest: np.ndarray | None = None  # (n, 2) ns spans at rest after the start (``rest``)
    heading_offset: np.ndarray | None = None  # (N,) base-z rate -> heading rate at the IMU stamps (``level``)

    @property
    def wheel_yaw_check(self) -> dict | None:
        """``wheel_yaw.YawCheck.to_dict()`` where the wheels' yaw rate was weighed."""
        return None if self.wheel_yaw_weighed is None else self.wheel_yaw_weighed.check

    @property
    def wheels_verified(self) -> bool:
        """The IMU verified the wheels: their speed scale measured by the accelerometer (``wheel_slip``, no slip left
        in) and their yaw rate agreeing with the gyro (``wheel_yaw``)."""
        speed, yaw = self.wheel_check or {}, self.wheel_yaw_check or {}
        return bool(speed.get("verified")) and bool(yaw.get("used"))

    @property
    def t0_ns(self) -> int:
        return self.coverage[0][0]

    @property
    def t1_ns(self) -> int:
        return self.coverage[-1][1]


def _runs(stamps: np.ndarray, gap_ns: int) -> list[tuple[int, int]]:
    if len(stamps) == 0:
        return []
    cut = np.flatnonzero(np.diff(stamps) > gap_ns)
    starts = np.concatenate([[0], cut + 1])
    ends = np.concatenate([cut, [len(stamps) - 1]])
    return [(int(stamps[a]), int(stamps[b])) for a, b in zip(starts, ends)]


def _merge(intervals: list[tuple[int, int]]) -> list[tuple[int, int]]:
    out: list[list[int]] = []
    for a, b in sorted(intervals):
        if out and a <= out[-1][1]:
            out[-1][1] = max(out[-1][1], b)
        else:
            out.append([a, b])
    return [(a, b) for a, b in out]


def in_coverage_gap(starts: list[int], ends: list[int], t_a: int, t_b: int) -> bool:
    """True when [t_a, t_b] lies between two covered stretches (no motion source has data there)."""
    k = bisect_right(starts, t_a) - 1
    return 0 <= k < len(starts) - 1 and t_a >= ends[k] and t_b <= starts[k + 1] and t_b > t_a


def gap_free_until(starts: list[int], ends: list[int], t: int) -> int:
    """A stamp up to which no step from ``t`` on can start in a coverage gap (``in_coverage_gap`` is False
    for every ``t <= t_a <`` it): the end of the covered stretch holding ``t``; ``t`` itself where none does
    or ``t`` is at its end. Stretches are merged, so the next starts after it."""
    k = bisect_right(starts, t) - 1
    return ends[k] if k >= 0 and t < ends[k] else t


def _inside(stamps: np.ndarray, coverage: list[tuple[int, int]]) -> np.ndarray:
    ok = np.zeros(len(stamps), bool)
    for a, b in coverage:
        ok |= (stamps >= a) & (stamps <= b)
    return ok


def _rate_stamps(coverage: list[tuple[int, int]], rate_hz: float) -> np.ndarray:
    """Stamps at ``rate_hz`` inside the coverage: on multiples of the period when it is a whole number of
    ns (so 200 Hz output meets 100 Hz ground truth), else from the start of each covered stretch."""
    period = 1e9 / rate_hz
    out = []
    for a, b in coverage:
        if float(period).is_integer():
            p = int(period)
            k0, k1 = -(-a // p), b // p
            out.append(np.arange(k0, k1 + 1, dtype=np.int64) * p)
        else:
            n = int(np.floor((b - a) / period)) + 1
            out.append(a + np.round(np.arange(n) * period).astype(np.int64))
    return np.unique(np.concatenate(out)) if out else np.zeros(0, np.int64)


def planar_use(use: dict[str, set[str]]) -> None:
    """The selection narrowed to what the planar EKF models (no accelerometer)."""
    if "imu" in use:
        use["imu"].discard("accel")
        if not use["imu"]:
            del use["imu"]


def prepare(inputs: FuseInputs, options: FuseOptions) -> Prepared:
    """Validate, clean and order the inputs; raise InputError/ConfigError with one line when no run can."""
    options.validate()
    use = resolve_use(inputs, options)
    if options.estimator == "planar":
        planar_use(use)
    motion = [s for s in MOTION_SOURCES if s in use and (s != "imu" or "gyro" in use["imu"])]
    if not motion:
        raise InputError("no motion source: fuse needs an odometry trajectory, an IMU (gyro) or wheel odometry")
    noise = options.noise
    reports = {s: SourceReport() for s in use}
    prep = Prepared(use, reports)
    runs: list[tuple[int, int]] = []
    if "imu" in use:
        prep.imu = clean_imu(inputs.imu, noise, reports["imu"])
        if len(prep.imu) == 0:
            if not ({"wheel", "odom"} & set(use)):
                raise InputError("the IMU has no usable sample (all NaN, out of range, all zero or duplicated) and there "
                                 "is no other motion source")
            prep.notes.append("IMU ignored: no usable sample (all NaN, out of range, all zero or duplicated)")
            prep.imu = None
            del use["imu"]
            if options.use is None and "wheel" in use:  # the default selection without a gyro
                use["wheel"].add("yaw_rate")
    if prep.imu is not None:
        prep.imu_w_b, prep.imu_f_b = imu_in_base(prep.imu)
        if "orientation" in use["imu"] and prep.imu.orientation_xyzw is not None:
            prep.imu_R_wb = orientation_to_base(prep.imu)
        prep.imu_gap_ns = gap_threshold_ns(prep.imu.stamps_ns, options.gap_periods, options.min_gap_ns)
        count_gaps(prep.imu.stamps_ns, prep.imu_gap_ns, reports["imu"])
        if "gyro" in use["imu"]:
            runs += _runs(prep.imu.stamps_ns, prep.imu_gap_ns)
    for name, clean, series in (("wheel", lambda s, r: clean_wheel(s, use["wheel"], noise, r), inputs.wheel),
                                ("odom", lambda s, r: clean_odom(s, noise, r), inputs.odom),
                                ("gps", lambda s, r: clean_gps(s, noise, r), inputs.gps)):
        if name not in use:
            continue
        cleaned = clean(series, reports[name])
        setattr(prep, name, cleaned)
        if name in MOTION_SOURCES:
            thr = gap_threshold_ns(cleaned.stamps_ns, options.gap_periods, options.min_gap_ns)
            count_gaps(cleaned.stamps_ns, thr, reports[name])
            runs += _runs(cleaned.stamps_ns, thr)
    if prep.gps is not None:
        prep.gps = drop_stale(prep.gps, prep.wheel, prep.odom, reports["gps"], prep.notes)
        assess_gps(prep.gps, reports["gps"], options.gps_jumps_ns)
    raw_wheel = prep.wheel  # before the weighing leaves yaw rates out
    weigh = options.use is None if options.weigh_wheel_yaw is None else options.weigh_wheel_yaw
    if weigh and prep.wheel is not None and prep.imu is not None and "gyro" in use["imu"] \
            and "yaw_rate" not in use["wheel"]:
        _weigh_wheel_yaw(prep, options)
    prep.coverage = _merge(runs)
    if not prep.coverage:
        raise InputError("no usable sample in any motion source")
    if prep.imu is not None and "gyro" in use["imu"]:
        find_gyro_gaps(prep, _runs(prep.imu.stamps_ns, prep.imu_gap_ns), raw_wheel)
    _check_clocks(prep)
    _output(prep, options)
    _events(prep, options.snap_ns)
    return prep


def _weigh_wheel_yaw(prep: Prepared, options: FuseOptions) -> None:
    """The wheels' yaw rate beside the gyro where the data show it agrees (``wheel_yaw``; the whole log's weighing
    where ``options.wheel_yaw`` holds it): into the selection, with its estimated variance and its slips left out
    (rejected as ``yaw_slip``)."""
    w = prep.wheel
    weighed = options.wheel_yaw
    if weighed is None:
        z = float(np.sqrt(chi2_thresholds(options.gate_probability, 1)[1]))
        check, yaw, var = weigh_yaw(w.stamps_ns, w.yaw_rate_radps, prep.imu.stamps_ns, prep.imu_w_b[:, 2],
                                    prep.imu_gap_ns, options.noise.gyro_noise_density, z, w.velocity_mps[:, 0])
        weighed = Weighed.of(w.stamps_ns, check, yaw, var)
    prep.wheel_yaw_weighed = weighed
    piece = weighed.on(w.stamps_ns, w.yaw_rate_radps)
    if piece is None:
        return
    yaw, var, far, unchecked = piece
    rep = prep.reports["wheel"]
    rep.reject("yaw_slip", far)
    rep.reject("yaw_unchecked", unchecked)
    rep.note("yaw_noise_estimated", int(np.isfinite(yaw).sum()))
    prep.wheel = replace(w, yaw_rate_radps=yaw, yaw_rate_var=var)
    prep.use["wheel"].add("yaw_rate")


def _check_clocks(prep: Prepared) -> None:
    """A selected source whose stamps all lie outside the others' span is on another clock: say so."""
    spans = {}
    for name in ("imu", "wheel", "odom", "gps"):
        s = getattr(prep, name)
        if s is not None and len(s):
            spans[name] = (int(s.stamps_ns[0]), int(s.stamps_ns[-1]))
    for name, (a, b) in spans.items():
        others = [v for k, v in spans.items() if k != name]
        if not others:
            continue
        lo, hi = min(v[0] for v in others), max(v[1] for v in others)
        if b < lo or a > hi:
            raise InputError(f"{name} stamps {a / 1e9:.3f}..{b / 1e9:.3f} s do not overlap the other sources' "
                             f"{lo / 1e9:.3f}..{hi / 1e9:.3f} s: the sources are on different clocks")


def _output(prep: Prepared, options: FuseOptions) -> None:
    if options.stamps_ns is not None:
        req = np.unique(np.asarray(options.stamps_ns, dtype=np.int64))
    elif options.rate_hz is not None:
        req = _rate_stamps(prep.coverage, options.rate_hz)
    elif prep.imu is not None and "gyro" in prep.use.get("imu", ()):
        req = prep.imu.stamps_ns
        if prep.gyro_gaps is not None:  # inside the gyro's gaps: the other motion sources' stamps
            other = [getattr(prep, s).stamps_ns for s in ("wheel", "odom") if getattr(prep, s) is not None]
            more = np.unique(np.concatenate(other)) if other else np.zeros(0, np.int64)
            more = more[in_gyro_gap(req, prep.imu_gap_ns, more)]
            prep.gyro_gaps.outputs = int(np.count_nonzero(_inside(more, prep.coverage)))
            req = np.union1d(req, more)
    else:
        req = np.unique(np.concatenate([getattr(prep, s).stamps_ns for s in ("wheel", "odom")
                                        if getattr(prep, s) is not None]))
    ok = _inside(req, prep.coverage)
    prep.out_stamps, prep.out_dropped = req[ok], int(np.count_nonzero(~ok))


def folded_outputs(prep: Prepared) -> tuple[list[int], list[int], list[int], list[bool]]:
    """The event stream as lists (times, kinds, indexes) plus ``out``: mark an output once the event is
    handled. An output right after another event at its stamp (outputs come last at a stamp) is folded into
    that event; one at a stamp of its own stays an event (``out`` True, nothing else to do), so a filter loop
    need not go round the folded ones."""
    t, k = prep.times, prep.kinds
    fold = np.zeros(len(t), bool)
    fold[1:] = (k[1:] == OUT) & (t[1:] == t[:-1]) & (k[:-1] != OUT)
    keep = ~fold
    out = k == OUT
    out[:-1] |= fold[1:]
    return t[keep].tolist(), k[keep].tolist(), prep.index[keep].tolist(), out[keep].tolist()


def snap_to(stamps: np.ndarray, grid: np.ndarray, tol_ns: int) -> tuple[np.ndarray, int]:
    """``stamps`` moved onto the nearest ``grid`` stamp where that is at most ``tol_ns`` away."""
    if tol_ns <= 0 or len(grid) == 0 or len(stamps) == 0:
        return stamps, 0
    j = np.clip(np.searchsorted(grid, stamps), 1, max(len(grid) - 1, 1))
    lo, hi = grid[j - 1], grid[np.minimum(j, len(grid) - 1)]
    near = np.where(stamps - lo <= hi - stamps, lo, hi)
    ok = np.abs(near - stamps) <= tol_ns
    return np.where(ok, near, stamps), int(np.count_nonzero(ok & (near != stamps)))


def _events(prep: Prepared, snap_ns: int) -> None:
    t0, t1 = prep.t0_ns, prep.t1_ns
    times, kinds, index = [], [], []
    imu_predicts = prep.imu is not None and "gyro" in prep.use.get("imu", ())
    imu_grid = prep.imu.stamps_ns if imu_predicts else np.zeros(0, np.int64)
    for kind, name in SOURCE_OF_KIND.items():
        s = getattr(prep, name)
        if s is None:
            continue
        st = s.stamps_ns
        inside = (st >= t0) & (st <= t1)
        prep.reports[name].reject("outside_span", int(np.count_nonzero(~inside)))
        idx = np.flatnonzero(inside)
        st = st[idx]
        if kind == WHEEL:  # the high-rate twist only: two odometry poses must never share a stamp
            st, n = snap_to(st, imu_grid, snap_ns)
            prep.reports[name].note("snapped", n)
        times.append(st)
        kinds.append(np.full(len(idx), kind, np.int8))
        index.append(idx)
    times.append(prep.out_stamps)
    kinds.append(np.full(len(prep.out_stamps), OUT, np.int8))
    index.append(np.arange(len(prep.out_stamps)))
    t = np.concatenate(times)
    k = np.concatenate(kinds)
    order = np.lexsort((k, t))
    prep.times, prep.kinds, prep.index = t[order], k[order], np.concatenate(index)[order]
