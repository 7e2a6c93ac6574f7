"""The static IMU scenario: noise statistics that match the requested densities and random walks (read back
from the log), pieces that join without a seam, bulk-serialised messages identical to the slow path."""

from __future__ import annotations

import json

import numpy as np
import pytest

from lio_cli.io.messages.decode import imu_sample
from lio_cli.io.logs.reader import open_log
from lio_cli.io.files.trajectory import read_tum
from lio_cli.io.logs.writer import LogWriter
from lio_cli.simulation import build_scenario, metrics_path_for, output_paths, simulate
from lio_cli.simulation.sensors import ImuSpec, synthesize_imu
from lio_cli.simulation.static import PIECE_SAMPLES, ImuEncoder, imu_pieces

NS = 1_000_000_000
START_NS = 1_700_000_000 * NS
SUFFIX = {"ros1": ".bag", "ros2": "", "ros2-mcap": "", "mcap": ".mcap"}
STD_RTOL = 0.03  # 12 001 samples x 3 axes: the std estimate spreads by ~0.4%


def _read_imu(out):
    with open_log(out) as log:
        samples = [imu_sample(m) for _, _, _, m in log.messages(["/imu"])]
    return (np.array([s[0] for s in samples]), np.array([s[1] for s in samples]), np.array([s[2] for s in samples]))


@pytest.mark.parametrize("fmt", ["ros1", "ros2", "mcap"])
def test_bulk_encoder_gives_the_writers_own_bytes(tmp_path, fmt):
    rng = np.random.default_rng(2)
    stamps = START_NS + np.sort(rng.integers(0, 10**13, 50))
    gyro, accel = rng.normal(0, 1, (50, 3)), rng.normal(0, 10, (50, 3))
    with LogWriter(tmp_path / f"x{SUFFIX[fmt]}", fmt) as wr:
        wr.add_topic("/imu", "sensor_msgs/msg/Imu")
        rows = ImuEncoder(wr, "imu").encode(stamps, gyro, accel)
        for i in range(50):
            slow = wr.serialize(wr.make.imu(int(stamps[i]), "imu", gyro[i], accel[i]), "sensor_msgs/msg/Imu")
            assert rows[i].tobytes() == slow


def test_pieces_join_without_a_seam():
    sc = build_scenario("static")
    spec = ImuSpec(accel_bias_walk=1e-2, gyro_bias_walk=1e-3)
    whole = synthesize_imu(sc.trajectory, sc.T_base_imu, spec, 0, 10 * NS, 0, None)
    pieces = list(imu_pieces(sc.trajectory, sc.T_base_imu, spec, 0, 10 * NS, 0, None, piece=300))
    assert len(pieces) == 7
    np.testing.assert_array_equal(np.concatenate([p.stamps_ns for p in pieces]), whole.stamps_ns)
    np.testing.assert_allclose(np.concatenate([p.accel_mps2 for p in pieces]), whole.accel_mps2, atol=1e-12)
    noisy = list(imu_pieces(sc.trajectory, sc.T_base_imu, spec, 0, 10 * NS, 0, np.random.default_rng(0), piece=300))
    bias = np.concatenate([p.accel_bias_mps2 for p in noisy])
    steps = np.diff(bias, axis=0)
    step_std = spec.accel_bias_walk * np.sqrt(0.005)
    np.testing.assert_allclose(steps.std(axis=0), step_std, rtol=0.1)
    seams = steps[np.arange(300, len(bias), 300) - 1]
    assert np.abs(seams).max() < 5 * step_std and (seams != 0).all()  # one walk step at each seam, no restart


def test_white_noise_matches_the_requested_densities(tmp_path):
    out = tmp_path / "white.mcap"
    simulate("static", out, duration_s=60.0, seed=5, accel_noise_density=3e-3, gyro_noise_density=2e-4,
             accel_bias_walk=0.0, gyro_bias_walk=0.0, accel_bias_mps2=(0.02, -0.03, 0.05),
             gyro_bias_radps=(1e-3, -2e-3, 5e-4))
    stamps, gyro, accel = _read_imu(out)
    assert len(stamps) == 12001 > PIECE_SAMPLES  # written in two pieces
    np.testing.assert_array_equal(stamps, START_NS + np.arange(12001, dtype=np.int64) * 5_000_000)
    np.testing.assert_allclose(accel.std(axis=0), 3e-3 * np.sqrt(200.0), rtol=STD_RTOL)
    np.testing.assert_allclose(gyro.std(axis=0), 2e-4 * np.sqrt(200.0), rtol=STD_RTOL)
    truth = json.loads(output_paths(out)[1].read_text())
    R_bi = np.asarray(truth["T_base_imu"])[:3, :3]
    mean_tol = 4 * 3e-3 * np.sqrt(200.0 / 12001)
    np.testing.assert_allclose(accel.mean(axis=0), R_bi.T @ [0, 0, 9.81] + [0.02, -0.03, 0.05], atol=mean_tol)
    np.testing.assert_allclose(gyro.mean(axis=0), [1e-3, -2e-3, 5e-4], atol=4 * 2e-4 * np.sqrt(200.0 / 12001))
    assert truth["allan"]["accelerometer_noise_density"] == 3e-3 and truth["allan"]["gyroscope_random_walk"] == 0.0
    assert truth["lidar"] is None and truth["wheel"] is None and truth["ground_truth"]["topic"] is None
    assert truth["imu"]["accel_bias_mps2"] == [0.02, -0.03, 0.05]
    gt_ns, gt_poses = read_tum(output_paths(out)[0])
    assert len(gt_ns) == 61 and np.ptp(gt_poses[:, :3, 3], axis=0).max() == 0.0  # 1 Hz, never moves
    metrics = json.loads(metrics_path_for(out).read_text())
    assert metrics["options"]["accel_noise_density"] == 3e-3 and metrics["topics"]["/imu"]["count"] == 12001


def test_bias_random_walk_matches_the_requested_density(tmp_path):
    """No white noise: readings minus the first one are the bias walk. Its steps have variance K^2 dt, are
    uncorrelated (white noise would give -0.5), and add up (variance over 1 s = 200 steps' worth)."""
    out = tmp_path / "walk.bag"
    simulate("static", out, duration_s=60.0, seed=6, accel_noise_density=0.0, gyro_noise_density=0.0,
             accel_bias_walk=4e-4, gyro_bias_walk=3e-5)
    _, gyro, accel = _read_imu(out)
    for data, k in ((accel, 4e-4), (gyro, 3e-5)):
        steps = np.diff(data, axis=0)
        np.testing.assert_allclose(steps.std(axis=0), k * np.sqrt(0.005), rtol=STD_RTOL)
        for j in range(3):
            assert abs(np.corrcoef(steps[:-1, j], steps[1:, j])[0, 1]) < 0.05
        one_s = data[200::200] - data[:-200:200]
        assert 0.7 < one_s.var() / (k * k * 1.0) < 1.3
    truth = json.loads(output_paths(out)[1].read_text())
    assert truth["imu"]["accel_bias_walk"] == 4e-4 and truth["allan"]["accelerometer_random_walk"] == 4e-4
    first, final = np.asarray(truth["imu"]["accel_bias_mps2"]), np.asarray(truth["imu"]["accel_bias_final_mps2"])
    R_bi = np.asarray(truth["T_base_imu"])[:3, :3]
    np.testing.assert_allclose(accel[0] - accel[-1], first - final, atol=1e-9)
    np.testing.assert_allclose(accel[0], R_bi.T @ [0, 0, 9.81] + first, atol=1e-9)


def test_static_refuses_what_it_does_not_have(tmp_path):
    from lio_cli.errors import ConfigError

    with pytest.raises(ConfigError, match=r"^--beams does not apply to the static scenario \(an IMU at rest, no LiDAR, "
                                          r"wheels or GPS\)$"):
        simulate("static", tmp_path / "s.mcap", duration_s=5.0, beams=32)
    with pytest.raises(ConfigError, match=r"^--duration 200000.0 s is more than 48 hours; simulate shorter pieces$"):
        simulate("static", tmp_path / "s.mcap", duration_s=200000.0)
    assert not any(tmp_path.iterdir())
