"""Each source's clock: the offsets given (``--imu-time-offset``, ``--time-offset SOURCE=SECONDS``) applied to its
stamps, every topic checked to be on one clock with them, and the lags the data show measured and reported."""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from ...config.fuse import FuseConfig
from ...core.fuse import FuseInputs
from ...core.fuse.clock_lag import Lag
from ...core.fuse.clock_lags import measure_lags
from ...io.logs.base import LogReader
from ...io.sensors.clocks import check_same_clock
from ...io.sensors.topics import TopicChoice

OTHERS = ("wheel", "gps", "odom")
SOURCE_NAME = {"wheel": "wheel odometry", "gps": "GPS", "odom": "odometry"}
WARN_SIGMAS = 4.0  # a lag this many 1-sigmas from the offset given is beyond noise
WARN_MIN_S = 0.05  # and this large matters (5 cm at 1 m/s) ...
WARN_MIN_M = 0.05  # ... or less where the base moves this far in it at its median moving speed ...
WARN_FLOOR_S = 0.005  # ... but never under this (one IMU period at 200 Hz)
MOVING_MPS = 0.2  # speeds above this count for that median


def offset_ns(cfg: FuseConfig, source: str) -> int:
    """The offset given for ``source`` (ns; 0 where none)."""
    if source == "imu":
        return cfg.calibration.imu_time_offset_ns
    return int(round(cfg.time_offsets_s.get(source, 0.0) * 1e9))


def option(source: str) -> str:
    """The option that shifts ``source``'s stamps, ready for its value."""
    return "--imu-time-offset" if source == "imu" else f"--time-offset {source}="


def shifted(series, shift_ns: int):
    """A core input series with ``shift_ns`` added to its stamps (the series itself where 0)."""
    return series if not shift_ns else replace(series, stamps_ns=series.stamps_ns + np.int64(shift_ns))


def check_clocks(reader: LogReader, roles: dict[str, TopicChoice], imu_offset_ns: int,
                 offsets_s: dict[str, float] | None = None) -> None:
    """Every source topic on one clock, each with its offset applied: the others against the first of them, then
    the IMU against it; a mismatch names the option (and value) that fixes it."""
    offsets_s = offsets_s or {}
    off = {s: int(round(offsets_s.get(s, 0.0) * 1e9)) for s in OTHERS}
    topics = {s: c.topic for s, c in roles.items() if c.topic is not None}
    others = [s for s in OTHERS if s in topics]
    for s in others[1:]:
        check_same_clock(reader, topics[others[0]], topics[s], off[s], option(s), off[others[0]], option(others[0]))
    if "imu" in topics and others:
        check_same_clock(reader, topics[others[0]], topics["imu"], imu_offset_ns, option("imu"), off[others[0]],
                         option(others[0]))


def clock_report(inputs: FuseInputs, cfg: FuseConfig) -> tuple[dict, list[str]]:
    """(metrics' ``clocks`` section, warnings): each source's measured lag against the IMU (its offsets applied),
    and a warning naming the option where a lag is beyond noise and large enough to matter."""
    lags = measure_lags(inputs)
    min_s = min(WARN_MIN_S, max(WARN_MIN_M / _speed_mps(inputs), WARN_FLOOR_S))
    out, notes = {}, []
    for src, sec in cfg.time_offsets_s.items():
        if getattr(inputs, src) is None:
            notes.append(f"{option(src)}{sec:g} given, but the run has no {SOURCE_NAME[src]}: not used")
    for src, lag in lags.items():
        given = cfg.time_offsets_s.get(src, 0.0)
        entry = {"given_s": given, **lag.to_dict()}
        if lag.offset_s is not None:
            entry["total_s"] = round(given + lag.offset_s, 4)
            if _matters(lag, min_s):
                notes.append(_warning(lag, given, cfg.calibration.imu_time_offset_s))
        out[src] = entry
    if out:
        out["meaning"] = ("offset_s: seconds to add to the source's stamps (beyond given_s) to line it up with the "
                          "IMU's gyro; total_s: the value for --time-offset SOURCE=; gain: the residual unshifted "
                          "over that at offset_s (a warning needs 1.2)")
    return out, notes


def _speed_mps(inputs: FuseInputs) -> float:
    """The base's median speed while it moves (the wheels', else the odometry's), m/s; 1 where neither tells."""
    v = np.zeros(0)
    if inputs.wheel is not None and len(inputs.wheel):
        v = np.abs(np.nan_to_num(inputs.wheel.velocity_mps[:, 0]))
    elif inputs.odom is not None and len(inputs.odom) > 1:
        od = inputs.odom
        v = np.linalg.norm(np.diff(od.poses[:, :3, 3], axis=0), axis=1) / np.maximum(np.diff(od.stamps_ns) * 1e-9, 1e-9)
    v = v[v > MOVING_MPS]
    return float(np.median(v)) if len(v) else 1.0


def _matters(lag: Lag, min_s: float) -> bool:
    return lag.clear and abs(lag.offset_s) >= max(WARN_SIGMAS * lag.sigma_s, min_s)


def _warning(lag: Lag, given: float, imu_given: float) -> str:
    """The lag and both ways out: the data tell only which clock runs late against which, not which is off."""
    late = "late" if lag.offset_s < 0 else "early"
    return (f"{lag.source}: stamps {abs(lag.offset_s):.3f} s {late} against the IMU (1-sigma "
            f"{lag.sigma_s * 1e3:.1f} ms, {lag.against}); if the IMU's clock is the one off give --imu-time-offset {imu_given - lag.offset_s:.3f}, "
            f"else give {option(lag.source)}{given + lag.offset_s:.3f}")


__all__ = ["check_clocks", "clock_report", "offset_ns", "option", "shifted"]
