"""``lio fuse --time-offset SOURCE=SECONDS``: bad values are one line on stderr, exit 2, nothing written; ``imu=``
is ``--imu-time-offset``; the value lands in the resolved config and a ``--config`` of it repeats the run."""

from __future__ import annotations

from pathlib import Path

import pytest
import yaml

from lio_cli.cli.app import main
from lio_cli.simulation.run import simulate


@pytest.fixture(scope="module")
def rover(tmp_path_factory) -> Path:
    log = tmp_path_factory.mktemp("fuse_offset") / "rover.bag"
    simulate("rover", log, duration_s=8.0, seed=3, lidar=False, gps=True)
    return log


def _run(capsys, *args) -> tuple[int, str, str]:
    code = main(["fuse", *map(str, args)])
    out, err = capsys.readouterr()
    return code, out, err


@pytest.mark.parametrize("value, message", [
    ("lidar=0.1", "--time-offset lidar=0.1: unknown source 'lidar' (choose from imu, wheel, odom, gps)"),
    ("gps=late", "--time-offset gps=late: 'late' is not a number of seconds"),
    ("gps=nan", "--time-offset gps=nan: must be a finite number of seconds within +-4e+09"),
    ("gps=inf", "--time-offset gps=inf: must be a finite number of seconds within +-4e+09"),
    ("gps", "--time-offset gps: expected SOURCE=SECONDS, e.g. gps=-0.3"),
    ("=0.3", "--time-offset =0.3: expected SOURCE=SECONDS, e.g. gps=-0.3"),
])
def test_a_bad_offset_is_one_line_and_writes_nothing(capsys, rover, tmp_path, monkeypatch, value, message):
    monkeypatch.chdir(tmp_path)
    code, out, err = _run(capsys, rover, "--time-offset", value, "--plot", "plots")
    assert code == 2 and out == ""
    assert err.strip() == f"lio: error: {message}"
    assert list(tmp_path.iterdir()) == []


def test_two_values_for_one_source_are_refused(capsys, rover, tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    code, _, err = _run(capsys, rover, "--time-offset", "gps=0.1", "--time-offset", "gps=0.2")
    assert (code, err.strip()) == (2, "lio: error: --time-offset gps given twice (0.1 and 0.2)")
    code, _, err = _run(capsys, rover, "--time-offset", "imu=0.01", "--imu-time-offset", "0.02")
    assert (code, err.strip()) == (2, "lio: error: --imu-time-offset 0.02 and --time-offset imu=0.01 disagree; give one")
    assert list(tmp_path.iterdir()) == []


def test_offsets_land_in_the_resolved_config_and_repeat(capsys, rover, tmp_path):
    out = tmp_path / "f.tum"
    code, _, err = _run(capsys, rover, "-o", out, "--time-offset", "gps=-0.25", "--time-offset", "imu=0.002",
                        "--time-offset", "wheel=0.01", "--rate", 20)
    assert code == 0, err
    cfg = yaml.safe_load((tmp_path / "f.fuse.config.yaml").read_text())
    assert cfg["time_offsets_s"] == {"gps": -0.25, "wheel": 0.01}
    assert cfg["calibration"]["imu_time_offset_s"] == 0.002
    again = tmp_path / "again.tum"
    code, _, err = _run(capsys, rover, "--config", tmp_path / "f.fuse.config.yaml", "-o", again)
    assert code == 0, err
    assert again.read_bytes() == out.read_bytes()


def test_help_shows_the_option_with_an_example(capsys):
    assert main(["fuse", "--help"]) == 0
    text = " ".join(capsys.readouterr().out.split())
    assert "--time-offset gps=-0.3" in text and "SOURCE=SECONDS" in text
