"""``lio simulate``: synthetic logs with exact ground truth (worlds, motions, sensor models, log output).

``simulate(scenario, out, fmt, duration_s, seed, **options)`` is the entry point; the pieces (analytic
trajectories, ray casting, IMU, wheel and GPS synthesis) are importable for tests and experiments.
"""

from .options import STARTS, TIME_CONVENTIONS, SimulationOptions
from .run import FORMATS, SimulationResult, metrics_path_for, output_paths, simulate
from .scenarios import ALL_SCENARIOS, SCENARIOS, Scenario, build_scenario

__all__ = [
    "ALL_SCENARIOS", "FORMATS", "SCENARIOS", "STARTS", "TIME_CONVENTIONS", "Scenario", "SimulationOptions",
    "SimulationResult", "build_scenario", "metrics_path_for", "output_paths", "simulate",
]
