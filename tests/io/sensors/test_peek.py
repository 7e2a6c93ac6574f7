"""The checks' peek at a topic's first messages: read from the bytes, it gives what the typestore gives in
every format, and a fuse run's topic and clock checks compile no typestore decoder."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest

from lio_cli.config.fuse import FuseConfig
from lio_cli.io.sensors.peek import _from_message, peek
from lio_cli.io.logs.base import LogReader
from lio_cli.io.logs.reader import open_log
from lio_cli.jobs.fuse.inputs import check_clocks, choose_sources

from .test_series import T0, _build


def _same(a, b) -> bool:
    return all(x == y or (math.isnan(x) and math.isnan(y)) for x, y in zip(a, b, strict=True))


def test_peek_from_bytes_equals_the_typestore_in_every_format(logs, write_format):
    path = logs.write(write_format, _build)
    with open_log(path) as log:
        for topic in ("/imu", "/odom", "/twist", "/pose"):
            got = list(peek(log, topic, 12))
            msgtype = log.topics[topic].msgtype
            want = [(rec.log_time_ns, *_from_message(log.deserialize(rec), msgtype))
                    for _, rec in zip(range(12), log.records([topic]))]
            assert len(got) == len(want) == 12
            for g, w in zip(got, want):
                assert g[:4] == w[:4], topic
                assert _same(g.values, w[4]), topic
    assert got[0].values == () and got[0].frame_id == "map"


def test_a_message_off_the_standard_layout_is_decoded_as_the_read_decodes_it(logs, monkeypatch):
    path = logs.write("ros1", _build)
    with open_log(path) as log:
        first = next(peek(log, "/imu", 1))
        real = log.records

        def padded(topics):  # a byte longer than the layout: another definition of the type
            for rec in real(topics):
                yield rec._replace(data=bytes(rec.data) + b"\0")

        monkeypatch.setattr(log, "records", padded)
        seen = []
        decode = log.decode
        monkeypatch.setattr(log, "decode", lambda rec: seen.append(rec.connection.topic) or decode(rec))
        again = next(peek(log, "/imu", 1), None)
    assert seen == ["/imu"]
    assert again == first  # LogReader.decode's Imu parser reads the standard fields in front of the extra byte


def test_fuse_checks_decode_nothing_through_the_typestore(logs, monkeypatch):
    """Topic choice (all-zero IMU, all-zero twist, frames) and the clock check on Imu and Odometry topics
    read the bytes: rosbags compiles a decoder per type on first use, which costs more than the checks."""
    def build(w):
        m = w.make
        w.add_topic("/imu", "sensor_msgs/msg/Imu")
        w.add_topic("/wheel/odom", "nav_msgs/msg/Odometry")
        for k in range(30):
            t = T0 + k * 10_000_000
            w.write("/imu", t + 1000, m.imu(t, "base_link", (0.0, 0.0, 0.1), (0.0, 0.0, 9.8)))
            w.write("/wheel/odom", t + 2000, m.odometry(t, "odom", "base_link", np.eye(4), (0.5, 0.0, 0.0),
                                                        (0.0, 0.0, 0.1)))

    path = logs.write("ros1", build)
    decoded = []
    monkeypatch.setattr(LogReader, "deserialize", lambda self, rec: decoded.append(rec.connection.topic))
    with open_log(path) as log:
        monkeypatch.setattr(log, "_deserialize", lambda raw, t, h: decoded.append(t))
        roles = choose_sources(log, FuseConfig())
        check_clocks(log, roles, 0)
    assert (roles["imu"].topic, roles["wheel"].topic) == ("/imu", "/wheel/odom")
    assert decoded == []


def test_a_cloud_is_peeked_by_lio_s_own_parser(monkeypatch):
    """The clock check reads the LiDAR topic's first stamps: a typestore decode of whole clouds for that."""
    with open_log(Path(__file__).resolve().parents[3] / "sample_logs" / "handheld.bag") as log:
        monkeypatch.setattr(log, "deserialize", lambda rec: pytest.fail("a cloud went through the typestore"))
        got = list(peek(log, "/points", 3))
    assert len(got) == 3 and all(p.frame_id == "lidar" and p.values == () for p in got)
    assert got[0].stamp_ns < got[1].stamp_ns < got[2].stamp_ns
