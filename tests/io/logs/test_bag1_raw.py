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


def _fields(header: bytes) -> dict[bytes, bytes]:
    """A record header's fields (length-prefixed ``name=value``), by name."""
    out, pos = {}, 0
    while pos < len(header):
        n = int.from_bytes(header[pos:pos + 4], "little")
        field = header[pos:pos + 4 + n]
        out[field[4:].split(b"=", 1)[0]] = field
        pos += 4 + n
    return out


@pytest.mark.parametrize("order", [(b"time", b"conn", b"op"), (b"op", b"conn", b"time"), (b"conn", b"op", b"time")])
def test_message_headers_in_any_field_order(tmp_path, order):
    """rosbag writes a message's header fields as time, conn, op; rosbags (so lio's own logs) as op, conn, time;
    anything else is read field by field: the same messages in every case. The bulk per-topic read knows the
    first two."""
    path = tmp_path / "order.bag"
    with Writer(path) as w:  # uncompressed chunks: the headers can be rewritten in place
        w.chunk_threshold = 64
        a = w.add_connection("/a", "std_msgs/msg/String", msgdef="string data", md5sum=MD5)
        for k in range(12):
            w.write(a, 100 + k, (3).to_bytes(4, "little") + b"m%02d" % k)
    data = bytearray(path.read_bytes())
    pos = data.find(b"\x04\x00\x00\x00op=\x02")
    rewritten = 0
    while pos >= 0:  # each message-data record: its header's three fields, permuted in place (same length)
        start = pos - 4
        hlen = int.from_bytes(data[start:start + 4], "little")
        fields = _fields(bytes(data[start + 4:start + 4 + hlen]))
        data[start + 4:start + 4 + hlen] = b"".join(fields[name] for name in order)
        rewritten += 1
        pos = data.find(b"\x04\x00\x00\x00op=\x02", start + 4 + hlen)
    path.write_bytes(bytes(data))
    assert rewritten == 12
    with Reader(path) as theirs, ColumnIndexReader(path) as ours:
        want = [(c.topic, t, bytes(d)) for c, t, d in theirs.messages(connections=theirs.connections)]
        got = [(topic, t, bytes(d)) for topic, _, t, d, _ in bag1_raw.messages(ours, ours.connections)]
        bulk = bag1_raw.connection_messages(ours, ours.connections, {})
    assert len(want) == 12 and got == want
    if order == (b"conn", b"op", b"time"):  # no layout it knows: the bulk read declines, messages reads them
        assert bulk is None
    else:  # rosbag's and rosbags' layouts: the bulk per-topic read gives the same bytes
        assert bulk == [[d for _, _, d in want]]


@pytest.mark.parametrize("compression", [None, "bz2", "lz4"])
def test_messages_as_views_of_pooled_chunks_are_rosbags_bytes(tmp_path, compression):
    """Chunks are read into reused buffers: messages as views (while others are read after them) and as bytes
    are rosbags' bytes, compressed chunks or not."""
    path = tmp_path / "chunks.bag"
    w = Writer(path)
    if compression is not None:
        w.set_compression(getattr(Writer.CompressionFormat, compression.upper()))
    with w:
        w.chunk_threshold = 256
        conn = w.add_connection("/a", "std_msgs/msg/String", msgdef="string data", md5sum=MD5)
        for k in range(200):
            body = bytes([k]) * (1 + 37 * k % 300)
            w.write(conn, 100 + k, len(body).to_bytes(4, "little") + body)
    with Reader(path) as theirs, ColumnIndexReader(path) as ours:
        want = [bytes(d) for _, _, d in theirs.messages()]
        views = [d for *_, d, _ in bag1_raw.messages(ours, ours.connections, {}, views=True)]
        copies = [d for *_, d, _ in bag1_raw.messages(ours, ours.connections, {})]
    assert len(want) == 200 and [bytes(v) for v in views] == want and copies == want
    assert all(type(c) is bytes for c in copies)
    if compression is None:  # an uncompressed chunk is its pooled buffer: views of it, read-only
        assert all(type(v) is memoryview and v.readonly for v in views)
