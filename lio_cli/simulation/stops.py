"""Stops mid-log (``--stop AT:SECONDS``): the platform brakes, stands exactly still, then drives on.

A stop is a time warp of the scenario's motion. The motion clock ``tau(t)`` runs at rate
``tau'(t) = 1 - sum_i bump_i(t)``, each bump rising 0 -> 1 with the quintic smooth-step over the
:data:`RAMP_S` before the stop's ``AT`` and falling 1 -> 0 over the :data:`RAMP_S` after ``AT + SECONDS``.
Between the two, ``tau`` is constant: the pose, the path progress, the sway and the bobbing all freeze and
velocity, angular rate and their derivatives are exactly zero. The unwarped kinematics at ``tau`` with the
chain rule give the warped ones, still exact, so synthesised IMU data integrates back to the ground truth.

``SECONDS`` counts the exact standstill only: the braking and driving-off ramps lie outside it.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from ..errors import ConfigError
from .motion import MotionState, Signal3, Trajectory, smoothstep, smoothstep_integral
from .sensors import NS

RAMP_S = 3.0  # braking and driving off: a car at 9 m/s brakes at up to 5.6 m/s^2
STOPS_MEANING = (f"the base stands exactly still (zero velocity and angular rate, pose and sway frozen) from "
                 f"start_ns to end_ns; it brakes smoothly over the {RAMP_S:g} s before (from brake_start_ns) and "
                 f"drives off over the {RAMP_S:g} s after (until drive_off_end_ns), resuming its motion where it "
                 f"paused; *_s are seconds since the log's start_ns; end_ns after the log's end_ns: the log ends parked")


def parse_stop(text: str) -> tuple[float, float]:
    """``"AT:SECONDS"`` -> (at_s, seconds), or a ConfigError naming ``--stop``."""
    parts = str(text).split(":")
    try:
        at_s, seconds = (float(p) for p in parts)
    except ValueError:
        raise ConfigError(f"--stop needs AT:SECONDS, two numbers of seconds such as 20:5 (got '{text}')") from None
    if not (math.isfinite(at_s) and math.isfinite(seconds)):
        raise ConfigError(f"--stop needs AT:SECONDS, two numbers of seconds such as 20:5 (got '{text}')")
    return at_s, seconds


def check_stops(stops, rest_s: float, duration_s: float) -> tuple[tuple[float, float], ...]:
    """The stops in time order as float pairs, or a ConfigError for the first that cannot work: each needs
    SECONDS > 0, its braking to begin after the start's rest (``rest_s``), AT inside the run, and its braking
    to begin after the previous stop has driven off."""
    pairs = []
    for stop in stops:
        try:
            at_s, seconds = (float(v) for v in stop)
        except (TypeError, ValueError):
            raise ConfigError(f"--stop needs AT:SECONDS, two numbers of seconds such as 20:5 (got {stop!r})") from None
        if not (math.isfinite(at_s) and math.isfinite(seconds)):
            raise ConfigError(f"--stop needs AT:SECONDS, two numbers of seconds such as 20:5 (got {at_s:g}:{seconds:g})")
        pairs.append((at_s, seconds))
    pairs.sort()
    for at_s, seconds in pairs:
        name = f"--stop {at_s:g}:{seconds:g}"
        if seconds <= 0:
            raise ConfigError(f"{name}: SECONDS must be positive")
        if at_s - RAMP_S < rest_s:
            raise ConfigError(f"{name}: braking takes the {RAMP_S:g} s before AT and the platform starts moving at "
                              f"{rest_s:g} s, so AT must be at least {rest_s + RAMP_S:g}")
        if at_s >= duration_s:
            raise ConfigError(f"{name}: AT must be before the run's end at {duration_s:g} s")
    for (a0, s0), (a1, s1) in zip(pairs, pairs[1:]):
        if a1 - RAMP_S < a0 + s0 + RAMP_S:
            raise ConfigError(f"--stop {a0:g}:{s0:g} and --stop {a1:g}:{s1:g} overlap: a stop drives off over the "
                              f"{RAMP_S:g} s after AT + SECONDS and brakes over the {RAMP_S:g} s before AT, so the "
                              f"later AT must be at least {a0 + s0 + 2 * RAMP_S:g}")
    return tuple(pairs)


def time_warp(stops: tuple[tuple[float, float], ...], t: np.ndarray) -> Signal3:
    """The motion clock ``tau`` and its first two derivatives at ``t`` (seconds) for time-ordered,
    non-overlapping ``stops``; tau is exactly constant, tau' and tau'' exactly zero, inside each standstill."""
    tau, d1, d2 = t.copy(), np.ones_like(t), np.zeros_like(t)
    lost = 0.0  # motion time paused by the stops before
    for at_s, seconds in stops:
        b0, e0, e1 = at_s - RAMP_S, at_s + seconds, at_s + seconds + RAMP_S
        frozen = at_s - 0.5 * RAMP_S - lost
        brake = (t > b0) & (t < at_s)
        s, s1, _ = smoothstep(t[brake], b0, RAMP_S)
        tau[brake] = t[brake] - lost - smoothstep_integral(t[brake], b0, RAMP_S)
        d1[brake], d2[brake] = 1.0 - s, -s1
        still = (t >= at_s) & (t <= e0)
        tau[still], d1[still], d2[still] = frozen, 0.0, 0.0
        drive = (t > e0) & (t < e1)
        s, s1, _ = smoothstep(t[drive], e0, RAMP_S)
        tau[drive] = frozen + smoothstep_integral(t[drive], e0, RAMP_S)
        d1[drive], d2[drive] = s, s1
        lost += seconds + RAMP_S
        after = t >= e1
        tau[after] = t[after] - lost
    return tau, d1, d2


@dataclass
class StoppedTrajectory:
    """A :class:`Trajectory` with stops: the same ``state``/``poses`` interface, the motion time-warped."""

    motion: Trajectory
    stops: tuple[tuple[float, float], ...]

    def state(self, t_s: np.ndarray) -> MotionState:
        t = np.atleast_1d(np.asarray(t_s, dtype=np.float64))
        tau, d1, d2 = time_warp(self.stops, t)
        u = self.motion.state(tau)
        k1, k2, kk = d1[:, None], d2[:, None], (d1 * d1)[:, None]
        # chain rule; + 0.0 turns the -0.0 of a standstill into 0.0
        return MotionState(t, u.position_m, u.velocity_mps * k1 + 0.0, u.accel_mps2 * kk + u.velocity_mps * k2 + 0.0,
                           u.R_world_base, u.omega_base_radps * k1 + 0.0,
                           u.alpha_base_radps2 * kk + u.omega_base_radps * k2 + 0.0)

    def poses(self, t_s: np.ndarray) -> np.ndarray:
        """T_world_base (N,4,4) at ``t_s``."""
        return self.state(t_s).poses


def stops_truth(stops: tuple[tuple[float, float], ...], start_ns: int) -> list[dict]:
    """truth.json's ``stops``: each standstill and its ramps, in seconds since ``start_ns`` and in ns."""

    def ns(t_s: float) -> int:
        return start_ns + int(round(t_s * NS))
    return [{"start_s": at_s, "end_s": round(at_s + seconds, 9), "duration_s": seconds,
             "start_ns": ns(at_s), "end_ns": ns(at_s + seconds),
             "brake_start_s": round(at_s - RAMP_S, 9), "brake_start_ns": ns(at_s - RAMP_S),
             "drive_off_end_s": round(at_s + seconds + RAMP_S, 9), "drive_off_end_ns": ns(at_s + seconds + RAMP_S)}
            for at_s, seconds in stops]
