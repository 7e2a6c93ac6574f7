"""A run's ``.config.yaml`` reused on another log or another OUT: a format that was detected (from the log or
OUT's suffix) does not bind the next run; one asked for (--format, --input-format) does."""

import pytest
import yaml
from rosbags.highlevel import AnyReader

from lio_cli.cli.app import main
from lio_cli.simulation.run import simulate


@pytest.fixture(scope="module")
def logs(tmp_path_factory):
    root = tmp_path_factory.mktemp("logs")
    kw = dict(duration_s=1.5, seed=4, columns=64, start="moving")
    return {fmt: simulate("handheld", root / f"walk_{fmt}{suffix}", fmt, **kw).log_path
            for fmt, suffix in (("ros1", ".bag"), ("mcap", ".mcap"), ("ros2", ""))}


def config(path) -> dict:
    return yaml.safe_load(path.read_text())


def storage(path) -> str:
    with AnyReader([path]) as r:  # opens only what it recognises: a ROS 1 bag named .mcap fails here
        return "ros2" if r.is2 else "ros1"


@pytest.mark.parametrize("command", ["odom", "fuse"])
def test_a_config_from_a_bag_run_serves_an_mcap_and_a_ros2_log(command, logs, tmp_path):
    first = tmp_path / "first.tum"
    assert main([command, str(logs["ros1"]), "-o", str(first), "-q"]) == 0
    cfg = tmp_path / f"first.{command}.config.yaml"
    assert config(cfg)["input"]["format"] is None
    for fmt in ("mcap", "ros2"):
        assert main([command, str(logs[fmt]), "-o", str(tmp_path / f"{fmt}.tum"), "--config", str(cfg), "-q"]) == 0
    again = tmp_path / "again.tum"  # the same log still repeats the run byte for byte
    assert main([command, str(logs["ros1"]), "-o", str(again), "--config", str(cfg), "-q"]) == 0
    assert again.read_bytes() == first.read_bytes()
    assert (tmp_path / f"again.{command}.config.yaml").read_bytes() == cfg.read_bytes()


def test_an_asked_input_format_is_kept(logs, tmp_path, capsys):
    out = tmp_path / "o.tum"
    assert main(["odom", str(logs["ros1"]), "-o", str(out), "--format", "ros1", "-q"]) == 0
    cfg = tmp_path / "o.odom.config.yaml"
    assert config(cfg)["input"]["format"] == "ros1"
    capsys.readouterr()
    assert main(["odom", str(logs["mcap"]), "-o", str(tmp_path / "m.tum"), "--config", str(cfg), "-q"]) == 2
    assert capsys.readouterr().err == (
        f"lio: error: {logs['mcap']}: is an MCAP file, not a ROS 1 bag as asked (--format, --input-format or "
        "input.format in --config; a .config.yaml written before this release pins the format it found: make it "
        "null)\n")


def test_deskew_config_reused_for_another_out_and_another_log(logs, tmp_path):
    first = tmp_path / "d.bag"
    assert main(["deskew", str(logs["ros1"]), str(first), "-q"]) == 0
    cfg = tmp_path / "d.deskew.config.yaml"
    assert config(cfg)["input"]["format"] is None and config(cfg)["output_format"] is None
    rep = tmp_path / "rep.mcap"
    assert main(["deskew", str(logs["ros1"]), str(rep), "--config", str(cfg), "-q"]) == 0
    assert storage(rep) == "ros2"  # an MCAP file, not a ROS 1 bag named .mcap
    assert main(["deskew", str(logs["mcap"]), str(tmp_path / "m.bag"), "--config", str(cfg), "-q"]) == 0
    assert storage(tmp_path / "m.bag") == "ros1"
    again = tmp_path / "again.bag"
    assert main(["deskew", str(logs["ros1"]), str(again), "--config", str(cfg), "-q"]) == 0
    assert again.read_bytes() == first.read_bytes()


def test_deskew_asked_output_format_is_kept(logs, tmp_path):
    assert main(["deskew", str(logs["ros1"]), str(tmp_path / "d.mcap"), "--format", "mcap", "-q"]) == 0
    assert config(tmp_path / "d.deskew.config.yaml")["output_format"] == "mcap"
