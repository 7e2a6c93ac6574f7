"""``clock_lag.measure_lags``: each source's stamps timed against the gyro on a weaving unicycle whose true
motion is known, each source stamped late by a known lag (the offset to give is minus the lag)."""

from __future__ import annotations

import numpy as np
import pytest

from lio_cli.core.fuse import FuseInputs, GpsSeries, ImuSeries, PoseSeries, WheelSeries
from lio_cli.core.fuse.clock_lags import measure_lags
from lio_cli.geometry import make_pose, so3_exp

T0_NS = 1_700_000_000 * 10**9
DURATION_S = 40.0
SPEED_MPS = 1.0
LAG_TOL_S = {"wheel": 0.01, "odom": 0.01,  # a shift half a wheel period (10 ms) or more off fails
             "gps": 0.05}  # 2 cm fixes at 1 m/s: 0.014 s apart from truth with a 0.014 s sigma


def _yaw_rate(t: np.ndarray) -> np.ndarray:
    return 0.3 * np.sin(2 * np.pi * 0.1 * t) + 0.2 * np.sin(2 * np.pi * 0.37 * t + 1.0)


def _heading(t: np.ndarray) -> np.ndarray:
    return (-0.3 / (2 * np.pi * 0.1) * (np.cos(2 * np.pi * 0.1 * t) - 1)
            - 0.2 / (2 * np.pi * 0.37) * (np.cos(2 * np.pi * 0.37 * t + 1.0) - np.cos(1.0)))


def _position(t: np.ndarray) -> np.ndarray:
    fine = np.arange(0.0, DURATION_S + 3.0, 0.001)
    v = SPEED_MPS * np.exp(1j * _heading(fine))
    p = np.concatenate([[0], np.cumsum(0.5 * (v[1:] + v[:-1]) * 0.001)])
    return np.interp(t, fine, p.real) + 1j * np.interp(t, fine, p.imag)


def _stamps(rate_hz: float, lag_s: float) -> tuple[np.ndarray, np.ndarray]:
    """(true instants s, header stamps ns stamped ``lag_s`` late)."""
    t = np.arange(0.0, DURATION_S, 1.0 / rate_hz)
    return t, T0_NS + np.round((t + lag_s) * 1e9).astype(np.int64)


def _inputs(lag: dict[str, float], gps_noise_m: float = 0.02, turning: float = 1.0, seed: int = 0) -> FuseInputs:
    rng = np.random.default_rng(seed)
    t, st = _stamps(200.0, 0.0)
    gyro = np.zeros((len(t), 3))
    gyro[:, 2] = turning * _yaw_rate(t) + rng.normal(0, 0.005, len(t))
    imu = ImuSeries(st, gyro, np.tile([0.0, 0.0, 9.81], (len(t), 1)))
    t, st = _stamps(50.0, lag.get("wheel", 0.0))
    vel = np.column_stack([np.full(len(t), SPEED_MPS), np.zeros(len(t)), np.zeros(len(t))])
    wheel = WheelSeries(st, vel, turning * _yaw_rate(t) + rng.normal(0, 0.02, len(t)))
    t, st = _stamps(10.0, lag.get("odom", 0.0))
    p = _position(t)
    poses = np.array([make_pose(so3_exp(np.array([0, 0, turning * h])), np.array([x.real, x.imag, 0.0]))
                      for h, x in zip(_heading(t), p)])
    odom = PoseSeries(st, poses)
    t, st = _stamps(5.0, lag.get("gps", 0.0))
    z = _position(t) + rng.normal(0, gps_noise_m, len(t)) + 1j * rng.normal(0, gps_noise_m, len(t))
    gps = GpsSeries(st, np.column_stack([z.real, z.imag, np.zeros(len(t))]))
    return FuseInputs(imu, wheel, odom, gps)


@pytest.mark.parametrize("source", ["wheel", "odom", "gps"])
@pytest.mark.parametrize("lag_s", [0.0, 0.1, 0.3, -0.3, 1.0])
def test_a_late_source_measures_minus_its_lag(source, lag_s):
    lags = measure_lags(_inputs({source: lag_s}))
    got = lags[source]
    assert got.offset_s == pytest.approx(-lag_s, abs=LAG_TOL_S[source])
    assert got.sigma_s < LAG_TOL_S[source] and got.trusted
    for other in {"wheel", "odom", "gps"} - {source}:  # the others stay on time
        assert abs(lags[other].offset_s) < LAG_TOL_S[other]


def test_without_turning_no_rate_is_timed():
    lags = measure_lags(_inputs({"wheel": 0.3}, turning=0.0))
    assert lags["wheel"].offset_s is None
    assert lags["wheel"].why == "too little turning to time its yaw rate against the gyro"
    assert lags["wheel"].to_dict() == {"measured": False, "why": lags["wheel"].why}


def test_fixes_that_scatter_metres_are_only_indicative():
    gps = measure_lags(_inputs({"gps": 0.3}, gps_noise_m=1.5))["gps"]
    assert not gps.trusted and gps.scatter_m > 1.0
    assert gps.to_dict()["indicative"].startswith("the fixes scatter")


def test_no_gyro_measures_nothing():
    inputs = _inputs({})
    inputs.imu = None
    assert measure_lags(inputs) == {}
