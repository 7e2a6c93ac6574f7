"""Hills for ground platforms (``--hills AMPLITUDE:WAVELENGTH``): the ground rises and falls along the path.

The ground's height is a function of the path parameter ``s`` that the trajectory's progress gives (about
metres of horizontal travel along the path, counted from the path's start as the scenario defines it, the
scenario's starting offset included; not from the log's first pose, so the log may start anywhere on a
hill): ``h(s) = A sin(2 pi s / L)``. The base rides ``h(s)`` above the scenario's height and bobbing, and
pitches with the grade: its pitch is ``-atan(h'(s))`` (``R = Rz(yaw) Ry(pitch) Rx(roll)`` points the forward
axis down for a positive pitch, so climbing is a negative pitch, nose up) plus the scenario's sway. The
forward axis then lies along the slope, and the forward velocity the wheels measure is the speed along the
ground. The path's horizontal progress is unchanged, so the speed along the slope is the horizontal speed
times ``sqrt(1 + h'(s)^2)`` (at most 4.4 % more at the steepest grade allowed).

Height is a function of distance travelled, not of place: a platform that laps a closed path sees the same
hills at the same place only when the lap length is a whole number of wavelengths.

Every derivative is exact (chain rule through ``s(t)``): height ``z' = h' s'``, ``z'' = h'' s'^2 + h' s''``;
grade angle ``theta = atan(h')``, ``theta_s = h'' / (1 + h'^2)``,
``theta_ss = h''' / (1 + h'^2) - 2 h' h''^2 / (1 + h'^2)^2``, ``theta' = theta_s s'``,
``theta'' = theta_ss s'^2 + theta_s s''``. So the IMU integrates back to the truth, a stop on a slope stands
exactly still with gravity tilted in the base frame, and the scenario's time warps (stops) apply unchanged.

The LiDAR world's ground is a flat plane: hills need ``--no-lidar``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from ..errors import ConfigError

MAX_AMPLITUDE_M = 50.0
MAX_GRADE = 0.3  # rise over run: 17 deg, about what a car's or a robot's wheels still climb
HILL_SCENARIOS = ("drive", "rover", "corridor", "planar")  # the wheeled ones: they follow the ground
HILLS_MEANING = ("the ground's height along the path: h(s) = amplitude_m * sin(2 pi s / wavelength_m), s the path "
                 "parameter (about metres of horizontal travel; start_s_m at start_ns); the base rides h(s) above "
                 "the scenario's height and bobbing and pitches with the grade, pitch = -atan(h'(s)) (nose up "
                 "climbing) plus the scenario's sway; max_grade = 2 pi amplitude_m / wavelength_m = max |h'(s)|; the "
                 "horizontal progress is the scenario's, so the speed along the slope (what the wheels measure) is "
                 "the horizontal speed * sqrt(1 + h'(s)^2)")

_NEEDS = "--hills needs AMPLITUDE:WAVELENGTH, two numbers of metres such as 2:150"
# (value, first derivative, second derivative) of a signal in time, as motion.Signal3
_Signal3 = tuple[np.ndarray, np.ndarray, np.ndarray]


@dataclass(frozen=True)
class Hills:
    """``h(s) = amplitude_m * sin(2 pi s / wavelength_m)`` along the path parameter ``s``."""

    amplitude_m: float
    wavelength_m: float

    @property
    def max_grade(self) -> float:
        """The steepest rise over run, ``max |h'(s)|``."""
        return 2.0 * math.pi * self.amplitude_m / self.wavelength_m

    def height(self, s: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """``h`` and its first three derivatives in ``s`` at ``s``."""
        ks = 2.0 * np.pi / self.wavelength_m * np.asarray(s, dtype=np.float64)
        k = 2.0 * np.pi / self.wavelength_m
        sn, cs = np.sin(ks), np.cos(ks)
        a = self.amplitude_m
        return a * sn, a * k * cs, -a * k * k * sn, -a * k**3 * cs

    def along(self, progress: _Signal3) -> tuple[_Signal3, _Signal3]:
        """(height, pitch) as signals in time for the path progress ``(s, s', s'')``: the height to add to the
        base's and the grade's pitch to add to its sway (negative climbing: nose up)."""
        s, sd, sdd = progress
        h, h1, h2, h3 = self.height(s)
        lift = (h, h1 * sd, h2 * sd * sd + h1 * sdd)
        q = 1.0 + h1 * h1
        th_s = h2 / q
        th_ss = h3 / q - 2.0 * h1 * h2 * h2 / (q * q)
        return lift, (-np.arctan(h1), -th_s * sd, -(th_ss * sd * sd + th_s * sdd))


def parse_hills(text: str) -> tuple[float, float]:
    """``"AMPLITUDE:WAVELENGTH"`` -> (amplitude_m, wavelength_m), or a ConfigError naming ``--hills``."""
    try:
        amplitude, wavelength = (float(p) for p in str(text).split(":"))
    except ValueError:
        amplitude = wavelength = math.nan
    if not (math.isfinite(amplitude) and math.isfinite(wavelength)):
        raise ConfigError(f"{_NEEDS} (got '{text}')")
    return amplitude, wavelength


def check_hills(hills, scenario: str, lidar: bool) -> tuple[float, float]:
    """``hills`` as a float pair, or a ConfigError for the first thing that cannot work: a scenario that does
    not drive on the ground, a LiDAR (its world's ground is flat), an amplitude outside 0..MAX_AMPLITUDE_M, a
    wavelength that is not positive or too short for wheels to climb the grade (above MAX_GRADE)."""
    try:
        amplitude, wavelength = (float(v) for v in hills)
    except (TypeError, ValueError):
        raise ConfigError(f"{_NEEDS} (got {hills!r})") from None
    name = f"--hills {amplitude:g}:{wavelength:g}"
    if not (math.isfinite(amplitude) and math.isfinite(wavelength)):
        raise ConfigError(f"{_NEEDS} (got {amplitude:g}:{wavelength:g})")
    if scenario not in HILL_SCENARIOS:
        raise ConfigError(f"--hills: the {scenario} scenario does not drive on the ground (hills apply to "
                          f"{', '.join(HILL_SCENARIOS[:-1])} and {HILL_SCENARIOS[-1]})")
    if lidar:
        raise ConfigError("--hills needs --no-lidar: the simulated world's ground is flat, so a LiDAR would see the "
                          "platform sink into it or float above it")
    if not 0.0 <= amplitude <= MAX_AMPLITUDE_M:
        raise ConfigError(f"{name}: AMPLITUDE must be within 0..{MAX_AMPLITUDE_M:g} m")
    if not wavelength > 0.0:
        raise ConfigError(f"{name}: WAVELENGTH must be positive")
    grade = Hills(amplitude, wavelength).max_grade
    if grade > MAX_GRADE:
        raise ConfigError(f"{name}: the steepest grade, 2 pi AMPLITUDE / WAVELENGTH = {grade:.3g} "
                          f"({math.degrees(math.atan(grade)):.1f} deg), is more than wheels climb ({MAX_GRADE:g}, "
                          f"{math.degrees(math.atan(MAX_GRADE)):.1f} deg): make WAVELENGTH at least "
                          f"{math.ceil(2.0 * math.pi * amplitude / MAX_GRADE):g} m")
    return amplitude, wavelength


def hills_truth(hills: Hills, start_s_m: float) -> dict:
    """truth.json's ``hills``: the terrain and where on it the log starts."""
    h, h1, _, _ = hills.height(np.array([start_s_m]))
    return {"amplitude_m": hills.amplitude_m, "wavelength_m": hills.wavelength_m, "max_grade": hills.max_grade,
            "max_grade_deg": math.degrees(math.atan(hills.max_grade)), "start_s_m": float(start_s_m),
            "start_height_m": float(h[0]), "start_grade": float(h1[0]), "meaning": HILLS_MEANING}
