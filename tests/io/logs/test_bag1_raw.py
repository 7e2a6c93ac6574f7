"""ROS 1 messages straight from the chunks: the order rosbags' reader gives, whatever the index blocks' size."""

from __future__ import annotations

import pytest
from rosbags.rosbag1 import Reader, Writer

from lio_cli.io.logs import bag1_raw
from lio_cli.io.logs.bag1_index import ColumnIndexReader

MD5 = "992ce8a1687cec8c8bd883ec73ca41d1"


@pytest.mark.parametrize("first, block", [(256, 8192), (2, 5), (1, 1)])
def test_blocks_of_index_entries_keep_rosbags_order(tmp_path, monkeypatch, first, block):
    monkeypatch.setattr(bag1_raw, "_FIRST_BLOCK", first)
    monkeypatch.setattr(bag1_raw, "_BLOCK", block)
    path = tmp_path / "ties.bag"  # equal times across connections, out-of-order records, several chunks
    with Writer(path) as w:
        w.chunk_threshold = 64
        a = w.add_connection("/a", "std_msgs/msg/String", msgdef="string data", md5sum=MD5)
        b = w.add_connection("/b", "std_msgs/msg/String", msgdef="string data", md5sum=MD5)
        for k, (conn, t) in enumerate([(b, 100), (a, 100), (a, 100), (b, 90), (a, 200)] * 8):
            w.write(conn, t + (k % 3), (3).to_bytes(4, "little") + b"m%02d" % k)
    with Reader(path) as theirs, ColumnIndexReader(path) as ours:
        want = [(c.topic, t, bytes(d)) for c, t, d in theirs.messages(connections=theirs.connections)]
        got = [(topic, t, bytes(d)) for topic, _, t, d, _ in bag1_raw.messages(ours, ours.connections)]
    assert len(want) == 40 and got == want
