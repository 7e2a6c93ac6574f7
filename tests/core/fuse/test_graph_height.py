"""The factor graph's height prior beside odometry (``graph.height``): on a short simulated drive on near-flat
ground whose odometry's pitch drifts (as a scan matcher's does), the height follows the IMU and wheels, not the
odometry's climb."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from lio_cli.core.fuse import FuseOptions, fuse
from lio_cli.core.fuse import choose
from lio_cli.core.fuse.graph import height
from lio_cli.evaluation import EvalOptions, Trajectory, evaluate
from lio_cli.simulation.fusion_case import OdomNoise, simulate_case

PITCH_DRIFT_RAD = np.radians(1.0)  # the odometry's pitch error at the end, grown linearly from 0
HEIGHT_RMS_M = 0.06  # vertical error after the SE(3) fit; measured: with the prior 0.034, without 0.103


def _pitch_drift(od, t0_ns: int, t1_ns: int):
    """The odometry's poses with a body pitch error growing to ``PITCH_DRIFT_RAD``: each increment of position
    taken along the tilted attitude, so the track climbs by its length times the error."""
    th = PITCH_DRIFT_RAD * (od.stamps_ns - t0_ns) / (t1_ns - t0_ns)
    P = od.poses.copy()
    for i in range(1, len(P)):
        c, s = np.cos(th[i - 1]), np.sin(th[i - 1])
        Ry = np.array([[c, 0.0, s], [0.0, 1.0, 0.0], [-s, 0.0, c]])
        R = od.poses[i - 1, :3, :3]
        P[i, :3, 3] = P[i - 1, :3, 3] + R @ Ry @ R.T @ (od.poses[i, :3, 3] - od.poses[i - 1, :3, 3])
        P[i, :3, :3] = od.poses[i, :3, :3] @ Ry
    return replace(od, poses=P, position_sigma_m=np.full(len(od), 0.02), rotation_sigma_rad=np.full(len(od), 0.005))


@pytest.fixture(scope="module")
def drifting_odometry():
    case = simulate_case("drive", 20.0, seed=3, wheels=True, wheel_errors=False,
                         odom=OdomNoise(position_sigma_m=0.003, drift_position_rw=0.005))
    od = _pitch_drift(case.inputs.odom, int(case.truth_stamps_ns[0]), int(case.truth_stamps_ns[-1]))
    return replace(case, inputs=replace(case.inputs, odom=od))


def _height_rms(case, res) -> float:
    ref = Trajectory(case.truth_stamps_ns, case.truth_poses, "gt")
    ev = evaluate(ref, Trajectory(res.stamps_ns, res.poses, "est"), EvalOptions(align="se3"))
    d = ev.association.ref.poses[:, 2, 3] - ev.est_aligned[:, 2, 3]
    return float(np.sqrt(np.mean(d**2)))


def test_the_height_follows_imu_and_wheels_not_the_odometry(drifting_odometry):
    case = drifting_odometry
    res = fuse(case.inputs, FuseOptions(estimator="ekf", rate_hz=20.0, smooth=True))
    sm = res.info["smoother"]
    assert sm["fallback"] is None and sm["height"]["priors"] > 0
    assert sm["height"]["sigma_m"] >= height.MIN_SIGMA_M
    assert _height_rms(case, res) < HEIGHT_RMS_M


def test_without_the_prior_the_height_follows_the_odometry(drifting_odometry, monkeypatch):
    monkeypatch.setattr(height, "ENABLED", False)
    res = fuse(drifting_odometry.inputs, FuseOptions(estimator="ekf", rate_hz=20.0, smooth=True))
    assert "height" not in res.info["smoother"]
    assert _height_rms(drifting_odometry, res) > HEIGHT_RMS_M


def test_a_platform_the_evidence_finds_tilting_gets_no_prior(drifting_odometry, monkeypatch):
    monkeypatch.setattr(choose, "MAX_TILT_DEG", 0.5)  # the drive's ground tilts it by 0.92 deg (95th percentile)
    res = fuse(drifting_odometry.inputs, FuseOptions(estimator="ekf", rate_hz=20.0, smooth=True))
    assert "height" not in res.info["smoother"]


def test_evidence_too_vague_to_hold_the_height_gets_no_prior(drifting_odometry, monkeypatch):
    monkeypatch.setattr(height, "MAX_SIGMA_M", 0.1)  # the drive's evidence: within 0.15 m of a plane
    res = fuse(drifting_odometry.inputs, FuseOptions(estimator="ekf", rate_hz=20.0, smooth=True))
    assert "height" not in res.info["smoother"]
