"""A log shorter than the IMU start-up window (issue 32): the IMU state never starts, and the LiDAR-only
trajectory is levelled by the mean specific force only when LiDAR and IMU agree the platform stood still. A car
driving off reads its 3.75 m/s^2 as a 21 deg tilt: levelled by it, a level drive climbed 8 cm in 0.3 s."""

from __future__ import annotations

import json

import numpy as np
import pytest

from lio_cli.cli.app import main
from lio_cli.io.files.trajectory import read_tum
from lio_cli.simulation.run import simulate

LEVEL_M = 0.03  # a flat road: the written trajectory's height change stays within registration noise
NOTE = ("the IMU state never started (the log is shorter than the start-up window): not levelled: the platform "
        "moved, and without the start-up window the IMU cannot tell its acceleration from gravity; the trajectory "
        "is in the first scan's base frame")


def _odom(tmp_path, start: str, capsys):
    log = simulate("drive", tmp_path / f"{start}.bag", "ros1", duration_s=0.45, seed=2, start=start).log_path
    out = tmp_path / "odom.tum"  # beside the log lie the simulator's own start.metrics.json and start.gt.tum
    assert main(["odom", str(log), "-o", str(out)]) == 0
    metrics = json.loads((tmp_path / "odom.metrics.json").read_text())
    return read_tum(out)[1][:, :3, 3], metrics, capsys.readouterr().err


def test_a_drive_off_shorter_than_the_start_up_window_does_not_climb_and_says_why(tmp_path, capsys):
    p, metrics, err = _odom(tmp_path, "accelerating", capsys)
    assert len(p) >= 3 and np.linalg.norm(p[-1, :2] - p[0, :2]) > 0.1  # it did drive
    assert np.abs(p[:, 2] - p[0, 2]).max() < LEVEL_M
    assert metrics["start"]["kind"] == "lidar-only" and metrics["start"]["levelled_by"] == "none"
    assert NOTE in metrics["notes"]
    assert NOTE in " ".join(err.split())  # on stderr too (wrapped to the terminal's width)


def test_standing_still_the_short_log_is_still_levelled_by_the_specific_force(tmp_path, capsys):
    p, metrics, _ = _odom(tmp_path, "still", capsys)
    assert metrics["start"]["levelled_by"] == "specific force"
    assert NOTE not in metrics["notes"]
    assert np.abs(p[:, 2] - p[0, 2]).max() < LEVEL_M
