"""calibrate and fuse on mountings as drivers publish them: a tree without base_link/base/base_footprint
(Ouster's os_sensor -> lidar, os_sensor -> imu) and extrinsics on /tf only. odom and deskew take the tree's
root as the base (``odom_inputs.root_base``); calibrate assumed the LiDAR was the base (identity) and kept a
lever arm of 0 where the walk cannot show it, and fuse refused the log, although /tf_static gives both."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from lio_cli.config.fuse import FuseConfig
from lio_cli.evaluation import EvalOptions, evaluate
from lio_cli.io.messages.decode import decode_tf
from lio_cli.io.logs.reader import open_log
from lio_cli.io.sensors.sources import load_trajectory
from lio_cli.io.logs.writer import LogWriter
from lio_cli.jobs.calibrate.job import CalibrateJob, run_calibrate
from lio_cli.jobs.fuse.job import FuseJob, run_fuse
from lio_cli.model.trajectory import Trajectory
from lio_cli.simulation.run import simulate

LEVER_M = (0.05, -0.02, 0.25)  # the IMU 15 cm above the LiDAR (base -> lidar z 0.1): a walk cannot show z
ROOT_NOTE = ("base frame 'os_sensor': the root of /tf_static's tree holding '{}' (none is named base_link, base, "
             "base_footprint; --base-frame chooses another)")


def _rewritten(src: Path, dst: Path, tf) -> Path:
    """``src`` with its /tf_static messages replaced by ``tf(writer, message)`` (a list of (topic, message))."""
    with open_log(src) as reader:
        topics = {t: i.msgtype for t, i in reader.topics.items()}
    with LogWriter(dst, "ros1") as w:
        for topic, msgtype in topics.items():
            w.add_topic(topic, msgtype)
        w.add_topic("/tf", topics["/tf_static"])
        with open_log(src) as reader:
            for topic, _, t_ns, msg in reader.messages():
                for out_topic, out in (tf(w, t_ns, msg) if topic == "/tf_static" else [(topic, msg)]):
                    w.write(out_topic, t_ns, out)
    return dst


@pytest.fixture(scope="module")
def walk(tmp_path_factory):
    root = tmp_path_factory.mktemp("trees")
    sim = simulate("handheld", root / "h.bag", "ros1", duration_s=8.0, seed=5, columns=512,
                   imu_rotation_deg=(0.0, 0.0, 180.0), imu_lever_arm_m=LEVER_M)
    truth = json.loads(Path(sim.truth_path).read_text())

    def ouster(w, t_ns, msg):
        return [("/tf_static", w.make.tf_message([w.make.transform_stamped(tr.stamp_ns, "os_sensor", tr.child, tr.pose)
                                                  for tr in decode_tf(msg)]))]

    def on_tf(w, t_ns, msg):  # the mountings repeated on /tf at 10 Hz, nothing on /tf_static
        trs = list(decode_tf(msg))
        return [("/tf", w.make.tf_message([w.make.transform_stamped(t_ns + k * 100_000_000, tr.parent, tr.child,
                                                                    tr.pose) for tr in trs])) for k in range(80)]

    logs = {"ouster": _rewritten(sim.log_path, root / "os.bag", ouster),
            "tf": _rewritten(sim.log_path, root / "tf.bag", on_tf)}
    return root, sim, truth, logs


def test_calibrate_takes_the_root_of_a_driver_tree_as_the_base(walk):
    """Before: T_base_lidar identity ("no T_base_lidar (base -> lidar) in /tf_static"), nothing to compare with,
    and the unobservable vertical lever arm kept at 0: T_lidar_imu 15 cm off in z."""
    root, _, truth, logs = walk
    r = run_calibrate(CalibrateJob(logs["ouster"], root / "os.calib.yaml"))
    cal = r.calibration
    assert r.metrics["base_frame"] == "os_sensor" and r.reference == "/tf_static"
    assert r.metrics["T_base_lidar_from"] == "/tf_static (os_sensor -> lidar)"
    assert ROOT_NOTE.format("lidar") in r.notes
    np.testing.assert_allclose(cal.matrix("T_base_lidar"), np.array(truth["T_base_lidar"]), atol=1e-6)
    np.testing.assert_allclose(cal.matrix("T_base_imu")[:3, 3], LEVER_M, atol=0.03)


def test_calibrate_says_its_reference_came_from_tf(walk):
    """Before: the table's column read "minus /tf_static" and the /tf mountings were taken without a word."""
    root, _, _, logs = walk
    r = run_calibrate(CalibrateJob(logs["tf"], root / "tf.calib.yaml"))
    assert r.reference == "/tf" and r.metrics["T_base_lidar_from"] == "/tf (base -> lidar)"
    assert any(n.startswith("/tf: base -> imu taken as a mounting") for n in r.notes)
    np.testing.assert_allclose(r.calibration.matrix("T_base_imu")[:3, 3], LEVER_M, atol=0.03)


def test_fuse_takes_the_root_of_a_driver_tree_as_the_base(walk):
    """Before: "IMU /imu is in frame 'imu' and neither /tf_static nor --calib gives T_base_imu (base -> imu)",
    exit 2, where odom and deskew ran on the same log."""
    _, sim, _, logs = walk
    cfg = FuseConfig.model_validate({"input": {"odom_topic": "/ground_truth"}, "rate_hz": 50.0,
                                     "use": {"imu": ["gyro", "accel"], "odom": ["pose"]}})
    run = run_fuse(FuseJob(logs["ouster"], cfg))
    assert run.metrics["base_frame"] == "os_sensor"
    assert run.metrics["extrinsics"]["T_base_imu"] == "/tf_static (os_sensor -> imu)"
    assert ROOT_NOTE.format("imu") in run.notes
    gt = load_trajectory(str(Path(sim.log_path).with_suffix(".gt.tum")))
    est = Trajectory(run.trajectory.stamps_ns, run.trajectory.poses, "est")
    assert evaluate(gt, est, EvalOptions(align="se3")).stats["ape"]["trans"]["rmse"] < 0.02
