"""``lio odom`` on a car already cruising at its first scan with no wheel odometry: only the LiDAR can tell the
speed, and its first registrations have nothing but a standstill to start from."""

from __future__ import annotations

import json

import numpy as np
import pytest

from lio_cli.cli.app import main
from lio_cli.evaluation.alignment import umeyama
from lio_cli.geometry import interpolate_poses
from lio_cli.io.files.trajectory import read_tum
import lio_cli.simulation.scenarios as scenarios
from lio_cli.simulation.motion import Progress, Sines
from lio_cli.simulation.run import simulate


@pytest.mark.parametrize("mount", [(0.0, 0.0, 0.0), (180.0, 0.0, 90.0)], ids=["aligned", "rotated"])
def test_a_car_cruising_from_its_first_scan_without_wheels_is_tracked(tmp_path, mount):
    """7.5 m/s is 0.75 m per 10 Hz sweep. The first LiDAR-only registrations stayed near their standstill guess
    for 8 scans, the start-up window took 1.8 m/s and the track was lost (ATE ~10 m over these 6 s)."""
    res = simulate("drive", tmp_path / "car.bag", "ros1", duration_s=6.0, seed=1, columns=360, start="moving",
                   wheel=False, imu_rotation_deg=mount)
    out = tmp_path / "o.tum"
    assert main(["odom", str(res.log_path), "-o", str(out), "-q"]) == 0
    start = json.loads(out.with_name("o.odom.metrics.json").read_text())["start"]
    gt_stamps, gt_poses = read_tum(res.gt_path)
    k = int(np.searchsorted(gt_stamps, start["stamp_ns"]))
    v_true = (gt_poses[k + 1, :3, 3] - gt_poses[k - 1, :3, 3]) / ((gt_stamps[k + 1] - gt_stamps[k - 1]) * 1e-9)
    assert start["kind"] == "moving" and start["speed_mps"] == pytest.approx(np.linalg.norm(v_true), rel=0.1), start
    stamps, poses = read_tum(out)
    ref = interpolate_poses(gt_stamps, gt_poses, stamps)[:, :3, 3]
    R, t, _ = umeyama(poses[:, :3, 3], ref, False)
    ate = np.sqrt(np.mean(np.sum((poses[:, :3, 3] @ R.T + t - ref) ** 2, axis=1)))
    assert len(stamps) == 60 and ate < 0.15, ate


def _ate(gt_path, est_path) -> float:
    gt_stamps, gt_poses = read_tum(gt_path)
    stamps, poses = read_tum(est_path)
    ref = interpolate_poses(gt_stamps, gt_poses, stamps)[:, :3, 3]
    R, t, _ = umeyama(poses[:, :3, 3], ref, False)
    return float(np.sqrt(np.mean(np.sum((poses[:, :3, 3] @ R.T + t - ref) ** 2, axis=1))))


def test_a_car_cruising_at_15_mps_from_its_first_scan_is_tracked(tmp_path, monkeypatch):
    """1.5 m per sweep, beyond the 1 m gate of the first LiDAR-only registrations from their standstill guess: they
    stayed near it, the IMU state started at 1.1 m/s and the track was lost (ATE 17 m over these 3 s). The drive's
    moving start at twice its speed, without its speed wobble, from the same place on the road."""
    def doubled(speed, t_rest_s=1.5, ramp_s=1.5, wobble=Sines(), s0_m=0.0):
        return Progress(2.0 * speed, t_rest_s, ramp_s, Sines(), s0_m - speed * 1.5)
    monkeypatch.setattr(scenarios, "Progress", doubled)
    res = simulate("drive", tmp_path / "car.bag", "ros1", duration_s=3.0, seed=1, columns=360, start="moving",
                   wheel=False)
    out = tmp_path / "o.tum"
    assert main(["odom", str(res.log_path), "-o", str(out), "-q"]) == 0
    start = json.loads(out.with_name("o.odom.metrics.json").read_text())["start"]
    assert start["kind"] == "moving" and start["speed_mps"] == pytest.approx(15.0, rel=0.05), start
    ate = _ate(res.gt_path, out)
    assert ate < 0.1, ate
