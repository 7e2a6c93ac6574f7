"""The factor graph's height prior beside odometry (``graph.height``): on a short simulated drive on near-flat
ground whose odometry's pitch drifts (as a scan matcher's does), the height follows the IMU and wheels, not the
odometry's climb."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from lio_cli.core.fuse import FuseOptions, fuse
from lio_cli.core.fuse import choose
from lio_cli.core.fuse.graph import height, wheels
from lio_cli.core.fuse.timeline import prepare
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


# --- wheels with a scale error and slips beside the odometry ----------------------------------------------------

SHORT = 1.05  # the wheels read the true speed over this


def _bad_wheels(case):
    """The case's wheels 5 % short with two smooth slips (30 % at their peak, 0.5 s sigma, at 6 and 13 s): ramps
    gentle enough that the IMU's own slip check (``choose.SLIP_MPS2``) misses their edges."""
    w = case.inputs.wheel
    t = (w.stamps_ns - w.stamps_ns[0]) * 1e-9
    v = w.velocity_mps / SHORT
    for c in (6.0, 13.0):
        v[:, 0] *= 1.0 + 0.3 * np.exp(-0.5 * ((t - c) / 0.5) ** 2)
    return replace(case, inputs=replace(case.inputs, wheel=replace(w, velocity_mps=v)))


@pytest.fixture(scope="module")
def bad_wheels(drifting_odometry):
    return _bad_wheels(drifting_odometry)


def test_the_wheels_scale_and_slips_are_found_against_the_odometry(bad_wheels):
    found = wheels.against_odometry(bad_wheels.inputs.wheel, bad_wheels.inputs.odom)
    assert abs(found.scale - SHORT) < 0.005  # measured 1.0472 (the slips' shoulders pull it up a little)
    mid = (found.slips_ns.mean(axis=1) - bad_wheels.truth_stamps_ns[0]) * 1e-9
    assert len(mid) and np.all(np.min(np.abs(mid[:, None] - np.array([6.0, 13.0])), axis=1) < 1.5)
    for c in (6.0, 13.0):  # each slip's peak window among them
        assert np.min(np.abs(mid - c)) < 0.6


def test_bad_wheels_beside_odometry_give_the_evidence_of_exact_ones(drifting_odometry, bad_wheels):
    o = FuseOptions(estimator="ekf")
    exact = height.level(prepare(drifting_odometry.inputs, o))
    lv = height.level(prepare(bad_wheels.inputs, o))
    # the IMU's slip check alone: the slips' ramps and the scale error read as pitch (measured climb 1.48 m,
    # tilt 9.3 deg: no prior, the old behaviour)
    assert choose.gravity_evidence(prepare(bad_wheels.inputs, o), height.SLIP_DILATE)["climb_m"] > height.MAX_SIGMA_M
    assert exact is not None and lv is not None
    assert lv.evidence["odom_slip_windows"] >= 2 and abs(lv.evidence["wheel_scale"] - SHORT) < 0.005
    # measured: 0.14 against 0.16 with exact wheels
    assert abs(lv.evidence["climb_m"] - exact.evidence["climb_m"]) < 0.05


def test_with_bad_wheels_the_height_still_follows_imu_and_wheels(bad_wheels):
    res = fuse(bad_wheels.inputs, FuseOptions(estimator="ekf", rate_hz=20.0, smooth=True))
    sm = res.info["smoother"]
    assert sm["fallback"] is None and sm["height"]["priors"] > 0
    assert _height_rms(bad_wheels, res) < HEIGHT_RMS_M  # measured 0.031; without the prior (the old evidence) 0.103


def test_odometry_whose_height_stays_within_the_prior_gets_none(drifting_odometry):
    """The same drive with the odometry's height as simulated (no pitch drift): IMU and wheels would hold it
    no better (measured: the odometry's extent 0.07 m, the evidence's climb 0.16 m)."""
    plain = simulate_case("drive", 20.0, seed=3, wheels=True, wheel_errors=False,
                          odom=OdomNoise(position_sigma_m=0.003, drift_position_rw=0.005))
    o = FuseOptions(estimator="ekf")
    assert height.level(prepare(plain.inputs, o)) is None
    lv = height.level(prepare(drifting_odometry.inputs, o))
    assert lv is not None and lv.evidence["odom_vertical_m"] > lv.sigma_m


def test_the_level_is_fitted_along_the_distance_not_the_median(drifting_odometry):
    """A pitch pattern whose mean is zero and median is not (+1.5, -0.75, -0.75 deg by window, added to the
    specific force): the median's level climbs by its offset times the path, the fitted one only wiggles."""
    prep = prepare(drifting_odometry.inputs, FuseOptions(estimator="ekf"))
    t = (prep.imu.stamps_ns - prep.imu.stamps_ns[0]) * 1e-9
    th = np.radians(np.array([1.5, -0.75, -0.75]))[np.floor(t / choose.WINDOW_S).astype(int) % 3]
    f = prep.imu_f_b.copy()
    f[:, 0], f[:, 2] = np.cos(th) * f[:, 0] + np.sin(th) * f[:, 2], -np.sin(th) * f[:, 0] + np.cos(th) * f[:, 2]
    skewed = replace(prep, imu_f_b=f)
    fitted = choose.gravity_evidence(skewed, level_fit=True)["climb_m"]
    median = choose.gravity_evidence(skewed)["climb_m"]
    # measured: median 0.98 m, fitted 0.34 m (0.16 m without the pattern; a window's +1.5 deg at 8 m/s is 0.2 m)
    assert median > 0.8
    assert fitted < 0.45
