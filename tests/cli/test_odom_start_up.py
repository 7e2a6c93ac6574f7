"""What ``lio odom`` loads: a plain run on a ROS 1 bag imports no module it does not use (the evaluation, the plots,
the map), and the options that need them still find them."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import pytest

from lio_cli.simulation.run import simulate

ROOT = Path(__file__).resolve().parents[2]
# run lio odom as the console script does, then write the names of the loaded modules to argv[1]
_RUN = ("import atexit, json, sys\n"
        "out = sys.argv.pop(1)\n"
        "atexit.register(lambda: open(out, 'w').write(json.dumps(sorted(sys.modules))))\n"
        "sys.argv[0] = 'lio'\n"
        "from lio_cli.cli.launch import entry\n"
        "entry()\n")
NOT_LOADED = ("lio_cli.evaluation", "lio_cli.plots", "lio_cli.jobs.plot", "lio_cli.jobs.odom.map")


@pytest.fixture(scope="module")
def bag(tmp_path_factory) -> Path:
    d = tmp_path_factory.mktemp("start_up")
    return simulate("handheld", d / "walk.bag", "ros1", duration_s=1.5, seed=0, force=True).log_path


def _loaded(tmp_path: Path, *args: str) -> set[str]:
    listing = tmp_path / "modules.json"
    env = {**os.environ, "PYTHONPATH": os.pathsep.join([str(ROOT), os.environ.get("PYTHONPATH", "")])}
    proc = subprocess.run([sys.executable, "-c", _RUN, str(listing), "odom", *args, "-q", "--force"], env=env,
                          capture_output=True, text=True, timeout=120)
    assert proc.returncode == 0, proc.stderr
    return set(json.loads(listing.read_text()))


def _under(modules: set[str], package: str) -> list[str]:
    return sorted(m for m in modules if m == package or m.startswith(package + "."))


def test_a_plain_run_on_a_ros1_bag_loads_only_what_it_uses(bag, tmp_path):
    out = tmp_path / "walk.tum"
    modules = _loaded(tmp_path, str(bag), "-o", str(out))
    assert len(out.read_text().splitlines()) >= 10  # the run did its work: 15 scans, from the 5th on
    assert {"rosbags.rosbag1", "kiss_icp", "lio_cli.core.odometry"} <= modules
    assert [m for p in NOT_LOADED for m in _under(modules, p)] == []


def test_the_options_that_need_more_load_it(bag, tmp_path):
    """--gt loads the evaluation, --map the map and --plot the plots, where a plain run left them out."""
    gt = bag.with_name("walk.gt.tum")
    modules = _loaded(tmp_path, str(bag), "-o", str(tmp_path / "walk.tum"), "--gt", str(gt), "--map",
                      str(tmp_path / "walk.ply"), "--plot", str(tmp_path / "plots"))
    assert _under(modules, "lio_cli.evaluation") and "lio_cli.jobs.odom.map" in modules
    assert "lio_cli.plots.trajectories" in modules and "lio_cli.jobs.plot" in modules
    assert json.loads((tmp_path / "walk.odom.metrics.json").read_text())["accuracy"]["ate_trans_rmse_m"] < 0.05
