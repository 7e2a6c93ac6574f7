"""``--calib`` against the log's /tf_static in odom, fuse and deskew: the log's mounting is used with a note
saying how far apart the two are; ``--prefer-calib`` (or ``calibration.prefer_file: true``) uses the file's."""

import json

import numpy as np
import pytest
import yaml

from lio_cli.cli.app import main
from lio_cli.geometry import make_pose, so3_exp
from lio_cli.simulation.run import simulate

NOTE = ("lio: warning: T_base_imu: /tf_static (base -> imu) and --calib are 5.00 cm and 10.000 deg apart; "
        "using {used}")


@pytest.fixture(scope="module")
def walk(tmp_path_factory):
    root = tmp_path_factory.mktemp("walk")
    res = simulate("handheld", root / "walk.bag", duration_s=3.0, seed=2, columns=360)
    truth = json.loads(res.truth_path.read_text())
    T = np.asarray(truth["T_base_imu"], float)
    # the file's mounting: 10 deg more about the IMU's z and 5 cm further along its x
    off = make_pose(so3_exp(np.array([0.0, 0.0, np.radians(10.0)])), np.array([0.05, 0.0, 0.0]))
    calib = root / "off.yaml"
    calib.write_text(yaml.safe_dump({"T_base_imu": (T @ off).tolist()}))
    return res, calib


def _run(capsys, *args) -> tuple[int, dict, str]:
    rc = main([str(a) for a in args])
    out, err = capsys.readouterr()
    return rc, json.loads(out) if out else {}, err


@pytest.mark.parametrize("command", ["odom", "fuse"])
def test_the_log_s_mounting_with_a_note_unless_prefer_calib(walk, tmp_path, capsys, command):
    res, calib = walk
    plain, told, preferred = (tmp_path / f"{n}.tum" for n in ("plain", "told", "preferred"))
    assert _run(capsys, command, res.log_path, "-o", plain, "-q")[0] == 0
    rc, m, err = _run(capsys, command, res.log_path, "--calib", calib, "-o", told, "--json", "-q")
    assert rc == 0 and NOTE.format(used="the log's (--prefer-calib uses --calib's)") in err.splitlines()
    assert told.read_bytes() == plain.read_bytes()  # the note changes nothing
    rc, m, err = _run(capsys, command, res.log_path, "--calib", calib, "--prefer-calib", "-o", preferred, "--json",
                      "-q")
    assert rc == 0 and NOTE.format(used="--calib's (--prefer-calib)") in err.splitlines()
    assert preferred.read_bytes() != plain.read_bytes()
    cfg = yaml.safe_load((tmp_path / f"preferred.{command}.config.yaml").read_text())
    assert cfg["calibration"]["prefer_file"] is True  # the written config repeats the choice
    assert m["extrinsics"]["T_base_imu"] == "--calib (--prefer-calib; the log has /tf_static (base -> imu))"


def test_the_config_key_is_the_flag(walk, tmp_path, capsys):
    res, calib = walk
    config = tmp_path / "prefer.yaml"
    config.write_text("calibration:\n  prefer_file: true\n")
    flag, key = tmp_path / "flag.tum", tmp_path / "key.tum"
    assert _run(capsys, "odom", res.log_path, "--calib", calib, "--prefer-calib", "-o", flag, "-q")[0] == 0
    assert _run(capsys, "odom", res.log_path, "--calib", calib, "--config", config, "-o", key, "-q")[0] == 0
    assert key.read_bytes() == flag.read_bytes()


def test_prefer_calib_without_calib_is_a_usage_error(walk, tmp_path, capsys):
    res, _ = walk
    rc, _, err = _run(capsys, "deskew", res.log_path, tmp_path / "d.bag", "--prefer-calib")
    assert (rc, err) == (2, "lio: error: --prefer-calib prefers the extrinsics of --calib: give --calib FILE\n")
    assert not (tmp_path / "d.bag").exists()
