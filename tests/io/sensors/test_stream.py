"""Topic choice and the merged, header-stamp-ordered SensorStream."""

from __future__ import annotations

import numpy as np
import pytest

from lio_cli.errors import InputError
from lio_cli.io.logs.reader import open_log
from lio_cli.model.records import ImuBatch, OdometryRecord, PointCloud, PoseRecord
from lio_cli.io.sensors.stream import SensorStream, read_imu, twist_problem
from lio_cli.io.sensors.topics import select_topic

IMU = "sensor_msgs/msg/Imu"
CLOUD = "sensor_msgs/msg/PointCloud2"


def two_imus_and_two_clouds(w):
    t = 1_000_000_000
    cloud = np.zeros(3, dtype=[("x", "<f4"), ("y", "<f4"), ("z", "<f4")])
    for topic, typ in (("/imu", IMU), ("/imu2", IMU), ("/points", CLOUD), ("/scan_b", CLOUD)):
        w.add_topic(topic, typ)
        msg = w.make.imu(t, "imu", [0, 0, 0], [0, 0, 9.81]) if typ == IMU else w.make.pointcloud2(t, "lidar", cloud)
        w.write(topic, t, msg)
    w.add_topic("/odom", "nav_msgs/msg/Odometry")


def test_select_topic_ignores_topics_without_messages(logs):
    path = logs.write("ros1", lambda w: (w.add_topic("/imu", IMU), w.add_topic("/points", CLOUD)))
    with open_log(path) as log:
        assert select_topic(log, "imu", required=False) is None
        with pytest.raises(InputError) as err:
            select_topic(log, "imu", "/imu")
        assert str(err.value) == f"{path}: topic /imu has no messages"
        # required: the declared topic is named, not "no LiDAR topic (none of type ...)" beside a declared one
        with pytest.raises(InputError) as err:
            select_topic(log, "lidar")
        assert str(err.value) == (f"{path}: no LiDAR data (/points is declared but never published); the log holds "
                                  "no message at all: check the recording")


def test_select_topic_picks_the_only_one(logs):
    path = logs.sensor_log("ros1", duration_s=0.2)
    with open_log(path) as log:
        assert select_topic(log, "lidar") == "/points"
        assert select_topic(log, "imu") == "/imu"
        assert select_topic(log, "wheel") == "/odom"
        assert select_topic(log, "gt") == "/ground_truth"  # PoseStamped; /odom is wheel odometry


def test_select_topic_with_several_lists_them_and_names_the_flag(logs):
    path = logs.write("mcap", two_imus_and_two_clouds)
    with open_log(path) as log:
        with pytest.raises(InputError) as err:
            select_topic(log, "imu")
        assert str(err.value) == f"{path}: several IMU topics (/imu, /imu2); choose one with --imu-topic"
        with pytest.raises(InputError) as err:
            select_topic(log, "lidar")
        assert str(err.value) == f"{path}: several LiDAR topics (/points, /scan_b); choose one with --lidar-topic"
        assert select_topic(log, "imu", "/imu2") == "/imu2"
        assert select_topic(log, "gt", required=False) is None  # Odometry not named as ground truth


def test_select_topic_unknown_and_wrong_type(logs):
    path = logs.write("ros2", two_imus_and_two_clouds)
    with open_log(path) as log:
        with pytest.raises(InputError) as err:
            select_topic(log, "imu", "/imu_nope")
        assert str(err.value) == f"{path}: topic /imu_nope not found; IMU topics here: /imu, /imu2"
        with pytest.raises(InputError) as err:
            select_topic(log, "lidar", "/imu")
        assert str(err.value) == (
            f"{path}: topic /imu is sensor_msgs/msg/Imu, not a LiDAR type (sensor_msgs/msg/PointCloud2, "
            "sensor_msgs/msg/LaserScan); LiDAR topics here: /points, /scan_b")
        with pytest.raises(InputError) as err:
            select_topic(log, "gt")
        assert str(err.value) == (f"{path}: no ground-truth topic (none of type geometry_msgs/msg/PoseStamped, "
                                  "geometry_msgs/msg/TransformStamped, nav_msgs/msg/Odometry)")


def test_stream_merges_topics_in_header_stamp_order(logs, write_format):
    # clouds are recorded 40 ms after their header stamp, IMU 1 us after: record order != stamp order
    path = logs.sensor_log(write_format, duration_s=0.5, lidar_delay_ns=40_000_000)
    with open_log(path) as log:
        stream = SensorStream(log, {"lidar": "/points", "imu": "/imu", "wheel": "/odom", "gt": "/ground_truth"})
        recs = list(stream)
    kinds = {r.kind for r in recs}
    assert kinds == {"lidar", "imu", "wheel", "gt"}
    # every IMU sample, every record, in non-decreasing header stamp
    firsts = [r.stamp_ns for r in recs]
    assert firsts == sorted(firsts)
    imu = ImuBatch.concat([r.data for r in recs if r.kind == "imu"])
    assert len(imu) == 50 and np.all(np.diff(imu.stamps_ns) > 0)
    for r in recs:
        if r.kind == "imu":  # a batch never spans another record
            later = [q.stamp_ns for q in recs if q.kind != "imu" and q.stamp_ns > r.stamp_ns]
            assert not later or r.data.stamps_ns[-1] <= min(later)
    clouds = [r.data for r in recs if r.kind == "lidar"]
    assert [c.stamp_ns for c in clouds] == [logs.T0_NS + i * 100_000_000 for i in range(5)]
    assert all(isinstance(c, PointCloud) and len(c.points) == 52 for c in clouds)
    assert all(isinstance(r.data, OdometryRecord) for r in recs if r.kind == "wheel")
    assert all(isinstance(r.data, PoseRecord) for r in recs if r.kind == "gt")
    assert stream.stats.messages == {"/points": 5, "/imu": 50, "/odom": 10, "/ground_truth": 5}


def test_stream_reorders_messages_recorded_out_of_stamp_order(logs):
    stamps = [0, 20, 10, 30, 50, 40, 60]  # ms; recorded in this order, each 1 ms after the previous

    def build(w):
        w.add_topic("/imu", IMU)
        for i, s in enumerate(stamps):
            w.write("/imu", logs.T0_NS + i * 1_000_000, w.make.imu(logs.T0_NS + s * 1_000_000, "imu", [s, 0, 0], [0, 0, 9.8]))

    path = logs.write("ros1", build)
    with open_log(path) as log:
        batch = read_imu(log, "/imu", strict=True)
    np.testing.assert_array_equal(batch.stamps_ns, logs.T0_NS + np.array(sorted(stamps)) * 1_000_000)
    np.testing.assert_array_equal(batch.gyro_radps[:, 0], sorted(stamps))


def test_imu_batches_are_bounded_and_carry_frame_and_units(logs):
    path = logs.sensor_log("ros2", duration_s=1.0, lidar_hz=1)
    with open_log(path) as log:
        recs = [r for r in SensorStream(log, {"imu": "/imu"}, imu_batch_size=32) if r.kind == "imu"]
    assert [len(r.data) for r in recs] == [32, 32, 32, 4]
    assert recs[0].data.frame_id == "imu_link" and recs[0].topic == "/imu"
    allb = ImuBatch.concat([r.data for r in recs])
    assert allb.gyro_radps.shape == (100, 3) and allb.accel_mps2.dtype == np.float64
    np.testing.assert_allclose(allb.accel_mps2[:, 2], 9.81)
    np.testing.assert_allclose(allb.gyro_radps[:, 0], 0.01 * np.arange(100))


def backwards_imu(logs):
    def build(w):
        w.add_topic("/imu", IMU)
        for i, s in enumerate([0, 10, 20, 900, 30, 40]):  # 900 ms jumps ahead, then stamps go back
            w.write("/imu", logs.T0_NS + i * 1_000_000_000, w.make.imu(logs.T0_NS + s * 1_000_000, "imu", [0, 0, 0], [0, 0, 9.8]))
    return logs.write("ros1", build)


def test_strict_stream_rejects_backwards_stamps_naming_topic(logs):
    path = backwards_imu(logs)
    with open_log(path) as log:
        with pytest.raises(InputError) as err:
            list(SensorStream(log, {"imu": "/imu"}))
    assert str(err.value) == (f"{path}: /imu: header stamps going backwards (1700000000.030000000 s after "
                              "1700000000.900000000 s); fix the log's stamps or re-record")


def test_lenient_stream_drops_and_counts_backwards_stamps(logs):
    path = backwards_imu(logs)
    with open_log(path) as log:
        stream = SensorStream(log, {"imu": "/imu"}, strict=False)
        batch = ImuBatch.concat([r.data for r in stream])
    assert len(batch) == 4 and stream.stats.backwards == {"/imu": 2}
    assert stream.stats.to_dict()["backwards_stamps_dropped"] == {"/imu": 2}


def empty_cloud_log(logs):
    def build(w):
        w.add_topic("/points", CLOUD)
        for i in range(3):
            arr, _ = logs.velodyne_cloud(8)
            if i == 1:
                arr["x"] = np.nan
            t = logs.T0_NS + i * 100_000_000
            w.write("/points", t, w.make.pointcloud2(t, "lidar", arr))
    return logs.write("mcap", build)


def test_strict_stream_rejects_cloud_with_zero_valid_points(logs):
    path = empty_cloud_log(logs)
    with open_log(path) as log:
        with pytest.raises(InputError) as err:
            list(SensorStream(log, {"lidar": "/points"}))
    assert str(err.value).startswith(f"{path}: /points: cloud at 1700000000.100000000 s has zero valid points (8 NaN/zero returns)")


def test_lenient_stream_skips_empty_clouds(logs):
    path = empty_cloud_log(logs)
    with open_log(path) as log:
        stream = SensorStream(log, {"lidar": "/points"}, strict=False)
        assert len(list(stream)) == 2
    assert stream.stats.empty_clouds == 1 and stream.stats.invalid_points == 8


def test_decode_errors_name_file_and_topic(logs):
    def build(w):
        w.add_topic("/points", CLOUD)
        arr = np.zeros(4, dtype=[("a", "<f4")])
        w.write("/points", logs.T0_NS, w.make.pointcloud2(logs.T0_NS, "lidar", arr))
    path = logs.write("ros2-mcap", build)
    with open_log(path) as log:
        with pytest.raises(InputError) as err:
            list(SensorStream(log, {"lidar": "/points"}))
    assert str(err.value) == f"{path}: /points: PointCloud2 has no x, y, z field(s); fields are ['a']"


def test_laserscan_topic_streams_as_planar_clouds(logs):
    def build(w):
        w.add_topic("/scan", "sensor_msgs/msg/LaserScan")
        for i in range(3):
            t = logs.T0_NS + i * 100_000_000
            w.write("/scan", t, w.make.laserscan(t, "laser", -1.0, 0.5, 1e-3, 0.1, 0.1, 10.0, [1.0, 2.0, np.inf, 3.0, 4.0]))
    path = logs.write("ros1", build)
    with open_log(path) as log:
        assert select_topic(log, "lidar") == "/scan"
        clouds = [r.data for r in SensorStream(log, {"lidar": "/scan"})]
    assert len(clouds) == 3 and all(c.planar and len(c.points) == 4 for c in clouds)
    np.testing.assert_array_equal(clouds[0].point_stamps_ns - logs.T0_NS, [0, 1_000_000, 3_000_000, 4_000_000])


def test_fast_raw_path_gives_what_the_typestore_path_gives(logs, write_format):
    from lio_cli.io.messages.decode import imu_sample
    from lio_cli.io.messages.pointcloud import decode_pointcloud2

    path = logs.sensor_log(write_format, duration_s=0.3)
    with open_log(path) as log:
        recs = list(SensorStream(log, {"lidar": "/points", "imu": "/imu"}))
        slow_clouds = [decode_pointcloud2(m) for _, _, _, m in log.messages(["/points"])]
        slow_imu = [imu_sample(m) for _, _, _, m in log.messages(["/imu"])]
    clouds = [r.data for r in recs if r.kind == "lidar"]
    imu = ImuBatch.concat([r.data for r in recs if r.kind == "imu"])
    assert len(clouds) == len(slow_clouds) == 3
    for fast, slow in zip(clouds, slow_clouds):
        np.testing.assert_array_equal(fast.points, slow.points)
        np.testing.assert_array_equal(fast.point_stamps_ns, slow.point_stamps_ns)
        assert (fast.frame_id, fast.stamp_ns, fast.convention) == (slow.frame_id, slow.stamp_ns, slow.convention)
    np.testing.assert_array_equal(imu.stamps_ns, [s for s, _, _ in slow_imu])
    np.testing.assert_array_equal(imu.gyro_radps, [g for _, g, _ in slow_imu])
    np.testing.assert_array_equal(imu.accel_mps2, [a for _, _, a in slow_imu])


def hostile_values_log(logs):
    """Three clouds (the second with one point 5e5 s off) and three IMU samples (the second at 1e300 m/s^2)."""
    def build(w):
        w.add_topic("/points", CLOUD)
        w.add_topic("/imu", IMU)
        for i in range(3):
            t = logs.T0_NS + i * 100_000_000
            arr, _ = logs.velodyne_cloud(8)
            if i == 1:
                arr["time"][4] = 5e5
            w.write("/points", t, w.make.pointcloud2(t, "lidar", arr))
            w.write("/imu", t, w.make.imu(t, "imu", [0, 0, 0], [1e300 if i == 1 else 0.0, 0, 9.81]))
    return logs.write("ros1", build)


@pytest.mark.parametrize("topic, message", [
    ("/points", "/points: cloud at 1700000000.100000000 s has 1 point(s) whose per-point time (velodyne: field "
                "'time' in s, relative to header) lies more than 1 s from the scan's other points"),
    ("/imu", "/imu: IMU sample at 1700000000.100000000 s holds an acceleration of 1e+300 m/s^2 (beyond 10000)"),
])
def test_strict_stream_reports_absurd_point_times_and_imu_values(logs, topic, message):
    path = hostile_values_log(logs)
    kind = "lidar" if topic == "/points" else "imu"
    with open_log(path) as log:
        with pytest.raises(InputError) as err:
            list(SensorStream(log, {kind: topic}))
    assert str(err.value).startswith(f"{path}: {message}")


def test_lenient_stream_drops_and_counts_absurd_point_times_and_imu_values(logs):
    path = hostile_values_log(logs)
    with open_log(path) as log:
        stream = SensorStream(log, {"lidar": "/points", "imu": "/imu"}, strict=False)
        recs = list(stream)
    assert sum(len(r.data.points) for r in recs if r.kind == "lidar") == 3 * 8 - 1
    assert sum(len(r.data) for r in recs if r.kind == "imu") == 2
    stats = stream.stats.to_dict()
    assert (stats["invalid_points_dropped"], stats["absurd_point_times_dropped"]) == (1, 1)
    assert stats["invalid_imu_samples_dropped"] == 1


def test_strict_stream_reports_a_stamp_of_0_that_sorts_first(logs):
    """A scan stamped 0 among 2023 stamps, early enough for the reorder window to put it first: never 'going
    backwards', but the header time then jumps 53 years while record time moves 0.1 s (reported); the lenient
    stream lets it through for the odometry's gap handling."""
    def build(w):
        w.add_topic("/points", CLOUD)
        for i in range(4):
            t = logs.T0_NS + i * 100_000_000
            arr, _ = logs.velodyne_cloud(8)
            w.write("/points", t, w.make.pointcloud2(0 if i == 1 else t, "lidar", arr))
    path = logs.write("ros1", build)
    with open_log(path) as log:
        with pytest.raises(InputError) as err:
            list(SensorStream(log, {"lidar": "/points"}))
        assert str(err.value).startswith(f"{path}: /points: header stamps jump from 0.000000000 s to "
                                         "1700000000.000000000 s between messages recorded -0.100 s apart")
        assert [r.stamp_ns for r in SensorStream(log, {"lidar": "/points"}, strict=False)][0] == 0


@pytest.mark.parametrize("linear,angular,problem", [
    ([1000.0, -1000.0, 0.0], [0.0, 0.0, -1000.0], None),  # at the limits: fine
    ([np.nan, 0.0, 0.0], [0.0, 0.0, 0.0], "holds NaN or infinity"),
    ([0.0, 0.0, 0.0], [0.0, np.inf, 0.0], "holds NaN or infinity"),
    ([0.0, -1500.0, 0.0], [0.0, 0.0, 0.0], "holds a speed of 1.5e+03 m/s (beyond 1000)"),
    ([0.0, 0.0, 0.0], [0.0, 0.0, 2000.0], "holds a turn rate of 2e+03 rad/s (beyond 1000)"),
    ([0.5, 0.0], [0.0, 0.0, 0.1], None),  # not three values: the general path
])
def test_twist_problem_names_the_first_unusable_value(linear, angular, problem):
    assert twist_problem(np.array(linear), np.array(angular)) == problem
