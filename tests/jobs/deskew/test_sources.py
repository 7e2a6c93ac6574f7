"""``lio deskew``'s motion sources against simulated truth, each beside the raw skew: constant velocity on a
PointCloud2 drive, a trajectory interpolated cubic or linear, of the base or of the LiDAR, from a file or a
log's topic, lio odom's own TUM, and the IMU to the scan start on a ROS 2 bag; and the line that says which."""

import json
from pathlib import Path

import numpy as np
import pytest

from lio_cli.cli.app import main
from lio_cli.io.messages.pointcloud import decode_pointcloud2
from lio_cli.io.files.trajectory import format_tum, read_tum
from lio_cli.jobs.odom.job import OdomJob, run_odom

from .test_job import clouds, deskew, errors, gt, sim  # noqa: F401 - sim is the module's fixture


def _stats(err: np.ndarray) -> tuple[float, float]:
    return float(np.median(err)), float(np.percentile(err, 95))


def test_constant_velocity_takes_out_most_of_a_drive_s_skew(sim, tmp_path):
    """No IMU used: LiDAR-only odometry, cubic between scans. A car's motion is close to constant velocity
    over a sweep: 23 / 122 mm median / p95 where the raw skew is 371 / 708 mm (3 s drive, 1024 columns)."""
    s = sim("ros1", scenario="drive", duration_s=3.0)
    res = deskew(s.log_path, tmp_path / "cv.bag", motion="constant-velocity")
    assert res.metrics["motion"]["source"] == "constant-velocity"
    err, skew = errors(s, tmp_path / "cv.bag")
    (med, p95), (skew_med, skew_p95) = _stats(err), _stats(skew)
    assert skew_med > 0.2
    assert med < 0.1 * skew_med and p95 < 0.25 * skew_p95, (med, p95, skew_med, skew_p95)


def test_a_trajectory_is_interpolated_cubic_or_linear_of_the_base_or_the_lidar(sim, tmp_path):
    """The true base trajectory (100 Hz): cubic through four poses 0.06 / 0.30 mm, linear between two 0.24 /
    1.30 mm, where the skew is 220 / 1615 mm (2 s walk). The same trajectory given as the LiDAR's poses
    (``trajectory.frame: lidar``) or read from the log's own topic gives the same points."""
    s = sim("ros1")
    deskew(s.log_path, tmp_path / "cubic.bag", **gt(s))
    deskew(s.log_path, tmp_path / "linear.bag", **gt(s), **{"trajectory.interpolation": "linear"})
    (cubic, skew), (linear, _) = errors(s, tmp_path / "cubic.bag"), errors(s, tmp_path / "linear.bag")
    assert np.median(skew) > 0.1
    assert _stats(cubic) < (0.0005, 0.002) and _stats(linear) < (0.002, 0.006)
    assert np.median(cubic) < 0.5 * np.median(linear)  # the cubic follows the sweep's curvature

    stamps, poses = read_tum(s.gt_path)
    T_base_lidar = np.asarray(json.loads(Path(s.truth_path).read_text())["T_base_lidar"])
    lidar_tum = tmp_path / "lidar.tum"
    lidar_tum.write_text(format_tum(stamps, poses @ T_base_lidar))
    deskew(s.log_path, tmp_path / "lidar.bag", **{"trajectory.path": str(lidar_tum), "trajectory.frame": "lidar"})
    deskew(s.log_path, tmp_path / "topic.bag", **{"trajectory.path": f"{s.log_path}:/ground_truth"})
    for name in ("lidar.bag", "topic.bag"):
        a, b = clouds(tmp_path / "cubic.bag"), clouds(tmp_path / name)
        assert len(a) == len(b) > 10
        for x, y in zip(a, b):
            np.testing.assert_allclose(decode_pointcloud2(y).points, decode_pointcloud2(x).points, atol=1e-4)
    # the LiDAR's poses as the base's would be a wrong trajectory: the check above can fail
    deskew(s.log_path, tmp_path / "wrong.bag", **{"trajectory.path": str(lidar_tum)})
    assert np.median(errors(s, tmp_path / "wrong.bag")[0]) > 5 * np.median(cubic)


def test_lio_odom_s_trajectory_takes_out_most_of_a_walk_s_skew(sim, tmp_path):
    """lio odom's TUM (a pose per scan, cubic between): 13 / 67 mm where the skew is 220 / 1615 mm; the sweep's
    rotation between two poses 0.1 s apart is what the IMU source gets better."""
    s = sim("ros1")
    res = run_odom(OdomJob(s.log_path))
    tum = tmp_path / "odom.tum"
    tum.write_text(format_tum(res.trajectory.stamps_ns, res.trajectory.poses))
    out = deskew(s.log_path, tmp_path / "odom.bag", **{"trajectory.path": str(tum)})
    assert out.metrics["scans"]["unchanged"] == 0
    err, skew = errors(s, tmp_path / "odom.bag")
    (med, p95), (skew_med, skew_p95) = _stats(err), _stats(skew)
    assert med < 0.03 and p95 < 0.12
    assert med < 0.15 * skew_med and p95 < 0.1 * skew_p95, (med, p95, skew_med, skew_p95)


def test_imu_motion_to_the_scan_start_on_a_ros2_bag(sim, tmp_path):
    """``--reference start`` with the IMU source: each cloud at its first valid point, which is its new stamp."""
    s = sim("ros2")
    out = tmp_path / "start"
    deskew(s.log_path, out, reference="start")
    err, skew = errors(s, out)
    assert np.median(skew) > 0.1
    assert np.median(err) < 0.015 and np.percentile(err, 95) < 0.05
    for raw, done in zip(clouds(s.log_path), clouds(out)):
        c, d = decode_pointcloud2(raw), decode_pointcloud2(done)
        assert d.stamp_ns == c.start_ns


@pytest.mark.parametrize("args,line", [
    ([], "motion: IMU: gyro rotation within each sweep (bias and clock offset as lio's IMU-primed odometry had "
         "them at that scan), translation from its 20 scan poses"),
    (["--motion", "constant-velocity"], "motion: LiDAR-only odometry (20 scan poses, constant-velocity prior), "
                                        "cubic interpolation between scans"),
])
def test_the_motion_used_is_said(sim, tmp_path, capsys, args, line):
    s = sim("ros1")
    assert main(["deskew", str(s.log_path), str(tmp_path / "o.bag"), *args]) == 0
    assert line in capsys.readouterr().err.splitlines()
