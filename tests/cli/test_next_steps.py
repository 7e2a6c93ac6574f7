"""Every "next: lio ..." line a command prints runs as printed, right after it, in the same folder (exit 0):
deskew's odometry on its output, also when the raw and the de-skewed clouds share the log (--topic-suffix)
and when the log needed --calib."""

import shlex

import pytest
import yaml

from lio_cli.cli.app import main
from lio_cli.simulation.run import simulate


@pytest.fixture(scope="module")
def walk(tmp_path_factory):
    root = tmp_path_factory.mktemp("walk")
    no_tf = simulate("handheld", root / "no_tf.bag", duration_s=2.5, seed=3, columns=360, tf_static=False)
    truth = yaml.safe_load(no_tf.truth_path.read_text())
    calib = root / "mount.yaml"
    calib.write_text(yaml.safe_dump({k: truth[k] for k in ("T_base_imu", "T_base_lidar")}))
    return simulate("handheld", root / "walk.bag", duration_s=2.5, seed=3, columns=360).log_path, no_tf.log_path, calib


def next_steps(err: str) -> list[list[str]]:
    return [shlex.split(line.removeprefix("next: "))[1:] for line in err.splitlines() if line.startswith("next: lio ")]


@pytest.mark.parametrize("case", ["plain", "topic-suffix", "calib"])
def test_deskew_s_next_step_runs_as_printed(walk, tmp_path, capsys, monkeypatch, case):
    log, no_tf, calib = walk
    monkeypatch.chdir(tmp_path)
    args = {"plain": ["deskew", log, "d.bag"], "topic-suffix": ["deskew", log, "d.bag", "--topic-suffix", "_d"],
            "calib": ["deskew", no_tf, "d.mcap", "--calib", calib]}[case]
    assert main([str(a) for a in args]) == 0
    steps = next_steps(capsys.readouterr().err)
    want = {"plain": "odom d.bag --deskew none", "topic-suffix": "odom d.bag --deskew none --lidar-topic /points_d",
            "calib": f"odom d.mcap --deskew none --calib {calib}"}[case]
    assert steps == [shlex.split(want)]
    assert main(steps[0]) == 0, capsys.readouterr().err
    assert (tmp_path / "d.odom.tum").exists() and (tmp_path / "d.deskew.metrics.json").exists()
