"""The ROS 1 reader whose index is read into columns: the same connections, index, chunks and messages as
rosbags' own reader, without building an index entry object per message at open."""

from __future__ import annotations

import pytest
from rosbags.rosbag1 import Reader, Writer
from rosbags.rosbag1 import reader as rosbag1_reader

from lio_cli.io.logs.bag1_index import ChunkIndexReader
from lio_cli.io.logs.reader import open_log

from ..sensors.test_series import _build

MD5 = "992ce8a1687cec8c8bd883ec73ca41d1"


def _same_as_rosbags(path) -> None:
    with Reader(path) as theirs, ChunkIndexReader(path) as ours:
        assert [c[:-1] for c in ours.connections] == [c[:-1] for c in theirs.connections]  # all but the owner
        assert [tuple(c) for c in ours.chunk_infos] == [tuple(c) for c in theirs.chunk_infos]
        assert list(ours.chunks) == list(theirs.chunks) and all(p in ours.chunks for p in theirs.chunks)
        assert [ours.chunks[p] for p in theirs.chunks] == list(theirs.chunks.values())  # sizes, decompressors
        assert -1 not in ours.chunks and [tuple(c) for c in ours.chunk_infos[-2:]] == \
            [tuple(c) for c in theirs.chunk_infos[-2:]]
        assert (ours.start_time, ours.end_time, ours.message_count) == \
            (theirs.start_time, theirs.end_time, theirs.message_count)
        assert ours.topics.keys() == theirs.topics.keys()
        for c in theirs.connections:  # IndexData compare by time only: compare them as plain tuples
            assert [tuple(e) for e in ours.indexes[c.id]] == [tuple(e) for e in theirs.indexes[c.id]]
            assert ours.columns([c.id])[c.id].T.tolist() == [list(e) for e in theirs.indexes[c.id]]
        assert [(c.id, t, bytes(d)) for c, t, d in ours.messages()] == \
            [(c.id, t, bytes(d)) for c, t, d in theirs.messages()]


def test_same_as_rosbags_reader_on_written_logs(logs, tmp_path):
    _same_as_rosbags(logs.write("ros1", _build))
    path = tmp_path / "ties.bag"  # equal times across connections, out-of-order records, several chunks
    with Writer(path) as w:
        w.chunk_threshold = 64
        a = w.add_connection("/a", "std_msgs/msg/String", msgdef="string data", md5sum=MD5)
        b = w.add_connection("/b", "std_msgs/msg/String", msgdef="string data", md5sum=MD5)
        w.add_connection("/unused", "std_msgs/msg/String", msgdef="string data", md5sum=MD5)
        for k, (conn, t) in enumerate([(b, 100), (a, 100), (a, 100), (b, 90), (a, 200)] * 6):
            w.write(conn, t + (k % 3), (3).to_bytes(4, "little") + b"m%02d" % (k % 100))
    _same_as_rosbags(path)


@pytest.mark.parametrize("name", ["jackal_imu_wheel/jackal.bag", "ardrone_twist_only/ardrone.bag"])
def test_same_as_rosbags_reader_on_real_logs(real_logs, name):
    _same_as_rosbags(real_logs / name)


def test_opening_and_reading_builds_no_index_entry_per_message(real_logs, monkeypatch):
    built = []
    entry = rosbag1_reader.IndexData
    monkeypatch.setattr(rosbag1_reader, "IndexData", lambda *a: built.append(a) or entry(*a))
    with open_log(real_logs / "jackal_imu_wheel" / "jackal.bag") as log:
        n = sum(1 for _ in log.raw_messages())
        assert log.topics["/imu/data"].count > 0 and log.topics["/imu/data"].first_ns is not None
    assert n > 6000 and built == []


def test_a_bag_without_messages_opens(tmp_path):
    path = tmp_path / "empty.bag"
    with Writer(path) as w:
        w.add_connection("/a", "std_msgs/msg/String", msgdef="string data", md5sum=MD5)
    with Reader(path) as theirs, ChunkIndexReader(path) as ours:
        assert [c[:-1] for c in ours.connections] == [c[:-1] for c in theirs.connections]
        assert ours.message_count == theirs.message_count == 0
        assert list(ours.messages()) == []


def test_rosbags_messages_of_one_connection_index_only_that_one(tmp_path, monkeypatch):
    """rosbags' own ``messages`` (lio's path for a bag split into several files) asks the index per connection:
    only the asked one's entries become ``IndexData``, not every topic's."""
    path = tmp_path / "three.bag"
    with Writer(path) as w:
        w.chunk_threshold = 64
        conns = [w.add_connection(f"/{n}", "std_msgs/msg/String", msgdef="string data", md5sum=MD5) for n in "abc"]
        for k in range(30):
            w.write(conns[k % 3], 100 + k, (3).to_bytes(4, "little") + b"m%02d" % k)
    built = []
    entry = rosbag1_reader.IndexData
    monkeypatch.setattr(rosbag1_reader, "IndexData", lambda *a: built.append(a) or entry(*a))
    monkeypatch.setattr("lio_cli.io.logs.bag1_index.IndexData", rosbag1_reader.IndexData)
    with ChunkIndexReader(path) as ours:
        got = [t for _, t, _ in ours.messages(connections=[ours.connections[2]])]
    assert got == list(range(102, 130, 3)) and len(built) == 10
