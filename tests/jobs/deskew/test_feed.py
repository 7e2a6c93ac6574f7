"""The deskew writing pass reads its log once: ``RecordFeed`` hands the writer every record in the log's order
while the IMU window reads ahead through it, and the window sees the same IMU as through a reader of its own."""

from pathlib import Path

import numpy as np
import pytest

from lio_cli.io.logs.reader import open_log
from lio_cli.jobs.deskew.motion import ImuWindow, RecordFeed
from lio_cli.simulation.run import simulate

SWEEP_NS = 100_000_000


@pytest.fixture(scope="module")
def log(tmp_path_factory) -> Path:
    root = tmp_path_factory.mktemp("feed")
    return simulate("handheld", root / "h.bag", "ros1", duration_s=1.5, seed=2, columns=64).log_path


def _key(rec):
    return rec.connection.topic, rec.log_time_ns, bytes(rec.data)


def test_feed_gives_every_record_once_in_order_while_the_imu_is_read_ahead(log):
    with open_log(log) as plain:
        expected = [_key(r) for r in plain.records()]
        imu_expected = [(t, m) for _, _, t, m in plain.messages(["/imu"], fast=True)]
    with open_log(log) as reader:
        feed = RecordFeed(reader, "/imu")
        imu = feed.messages()
        seen_imu, written = [], []
        for rec in feed:
            written.append(_key(rec))
            if rec.connection.topic == "/points":  # at a sweep the window reads 40 IMU samples ahead
                for _ in range(40):
                    got = next(imu, None)
                    if got is None:
                        break
                    seen_imu.append(got)
        seen_imu.extend(imu)
    assert written == expected
    assert len(imu_expected) > 100
    assert [(t, m) for _, _, t, m in seen_imu] == imu_expected


def test_window_on_the_feed_equals_window_on_its_own_reader(log):
    """Each sweep asks with its own clock offset (the odometry's at that scan): the samples come on the LiDAR's
    clock, their IMU stamps moved by it."""
    with open_log(log) as reader:
        sweeps = [t for _, _, t, _ in reader.messages(["/points"])]
    own = ImuWindow(log, None, "/imu")
    fed = ImuWindow(log, None, "/imu")
    with open_log(log) as reader:
        stamps = np.array([t for _, _, t, _ in reader.messages(["/imu"])], dtype=np.int64)
    with open_log(log) as reader:
        feed = RecordFeed(reader, "/imu")
        fed.attach(feed)
        records = iter(feed)
        for i, t1 in enumerate(sweeps):
            for rec in records:  # the writer's position: this sweep's record
                if rec.connection.topic == "/points" and rec.log_time_ns == t1:
                    break
            offset = 1_000_000 * (i % 3 - 1)
            a, b = own.covering(t1 - SWEEP_NS, t1, offset), fed.covering(t1 - SWEEP_NS, t1, offset)
            assert len(a) > 0 and a.frame_id == b.frame_id
            assert np.isin(a.stamps_ns - offset, stamps).all()  # the IMU's stamps, moved by this sweep's offset
            assert a.stamps_ns[-1] >= t1 and a.stamps_ns[0] <= t1 - SWEEP_NS
            assert np.array_equal(a.stamps_ns, b.stamps_ns)
            assert np.array_equal(a.gyro_radps, b.gyro_radps) and np.array_equal(a.accel_mps2, b.accel_mps2)
        assert fed.reader is None  # no second reader was opened
    own.close()
    fed.close()
