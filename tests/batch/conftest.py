"""Short simulated logs for the batch tests (built once per session) and the single-command results a batch
must reproduce byte for byte: ``lio odom LOG -o REF/NAME.tum --gt /ground_truth``, run one after another."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import pytest

from lio_cli.cli.app import main
from lio_cli.simulation.run import simulate

DURATION_S = 4.0
# name -> (scenario, file suffix, seed, ATE threshold in m: IMU-primed odometry stays under it on these logs)
LOGS = {
    "walk_a": ("handheld", ".bag", 1, 0.02),
    "walk_b": ("handheld", ".bag", 2, 0.03),
    "office": ("planar", ".mcap", 3, 0.02),
}


@dataclass
class Sim:
    root: Path
    logs: dict[str, Path]  # name -> log
    ref: Path  # folder of the single-command outputs: NAME.tum, NAME.odom.config.yaml, NAME.odom.metrics.json
    thresholds: dict[str, float]

    def ref_files(self, name: str) -> dict[str, Path]:
        return {"tum": self.ref / f"{name}.tum", "config": self.ref / f"{name}.odom.config.yaml",
                "metrics": self.ref / f"{name}.odom.metrics.json"}


@pytest.fixture(scope="session")
def sim(tmp_path_factory) -> Sim:
    root = tmp_path_factory.mktemp("batch_sim")
    logs = {}
    (root / "logs").mkdir()
    for name, (scenario, suffix, seed, _) in LOGS.items():
        logs[name] = simulate(scenario, root / "logs" / f"{name}{suffix}", duration_s=DURATION_S, seed=seed).log_path
    ref = root / "ref"
    ref.mkdir()
    for name, log in logs.items():
        assert main(["odom", str(log), "-o", str(ref / f"{name}.tum"), "--gt", "/ground_truth", "-q"]) == 0
    return Sim(root, logs, ref, {n: v[3] for n, v in LOGS.items()})
