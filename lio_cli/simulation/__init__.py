"""``lio simulate``: synthetic logs with exact ground truth (worlds, motions, sensor models, log output).

``simulate(scenario, out, fmt, duration_s, seed, **options)`` is the entry point; the pieces (analytic
trajectories, ray casting, IMU and wheel synthesis) are importable for tests and experiments.
"""

from .run import FORMATS, TIME_CONVENTIONS, SimulationOptions, SimulationResult, output_paths, simulate
from .scenarios import SCENARIOS, Scenario, build_scenario

__all__ = [
    "FORMATS", "SCENARIOS", "TIME_CONVENTIONS", "Scenario", "SimulationOptions", "SimulationResult",
    "build_scenario", "output_paths", "simulate",
]
