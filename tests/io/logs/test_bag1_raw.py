"""ROS 1 messages straight from the chunks: the order rosbags' reader gives, whatever the index blocks' size."""

from __future__ import annotations

import numpy as np
import pytest
from rosbags.rosbag1 import Reader, Writer

from lio_cli.io.logs import bag1_raw
from lio_cli.io.logs.bag1_index import ChunkIndexReader

MD5 = "992ce8a1687cec8c8bd883ec73ca41d1"


def _messy_bag(path, seed: int, threshold: int) -> None:
    """Three connections (one never written), times with ties within and across connections, written out of
    order: chunks whose time ranges overlap and chunk infos out of time order."""
    rng = np.random.default_rng(seed)
    with Writer(path) as w:
        w.chunk_threshold = threshold
        conns = [w.add_connection(f"/{n}", "std_msgs/msg/String", msgdef="string data", md5sum=MD5) for n in "abc"]
        w.add_connection("/unused", "std_msgs/msg/String", msgdef="string data", md5sum=MD5)
        times = np.sort(rng.integers(0, 40, 150)) * 1_000 + 10**9  # many equal times
        times[rng.random(150) < 0.3] -= 25_000  # late records: chunk time ranges overlap
        times[100:130] = times[100:130][::-1] + 60_000  # a run written newest first
        for k, t in enumerate(times.tolist()):
            w.write(conns[int(rng.integers(0, 3))], t, (3).to_bytes(4, "little") + b"%03d" % k)


@pytest.mark.parametrize("seed, threshold, at_once", [(0, 64, 1), (1, 200, 3), (2, 1, 8), (3, 10_000, 8), (4, 64, 2)])
def test_index_read_chunk_by_chunk_keeps_rosbags_order(tmp_path, monkeypatch, seed, threshold, at_once):
    """The index read again chunk by chunk (``at_once`` chunks at a time) as the stream reaches each gives the
    messages of rosbags' whole-index read in the same order (record time; ties connection by connection in the
    order asked, each in its order in the index), for any connections asked in any order, some twice."""
    monkeypatch.setattr(bag1_raw, "CHUNKS_AT_ONCE", at_once)
    path = tmp_path / "messy.bag"
    _messy_bag(path, seed, threshold)
    with Reader(path) as theirs, ChunkIndexReader(path) as ours:
        firsts = [min(e.time for c in theirs.connections for e in theirs.indexes[c.id] if e.chunk_pos == i.pos)
                  for i in theirs.chunk_infos]
        if threshold < 1_000:  # several chunks, their infos out of time order and their time ranges overlapping
            assert len(firsts) > 5 and firsts != sorted(firsts)
            assert any(a.end_time > b.start_time for a, b in zip(theirs.chunk_infos, theirs.chunk_infos[1:]))
        t_c = {c.topic: c for c in theirs.connections}
        o_c = {c.topic: c for c in ours.connections}
        for topics in (["/a", "/b", "/c", "/unused"], ["/c", "/a"], ["/b"], ["/b", "/a", "/b"], ["/unused"]):
            want = [(c.topic, t, bytes(d)) for c, t, d in theirs.messages(connections=[t_c[n] for n in topics])]
            got = [(topic, t, bytes(d)) for topic, _, t, d, _ in bag1_raw.messages(ours, [o_c[n] for n in topics])]
            assert got == want
            assert (len(want) > 0) == (topics != ["/unused"])
        assert sum(c.msgcount for c in ours.connections) == 150


def test_the_stream_reads_a_chunks_index_only_once_it_is_reached(tmp_path, monkeypatch):
    """No chunk's index is read before the stream has handed on every message earlier than that chunk's first:
    the index held is that of the chunks the stream is in, not the bag's."""
    path = tmp_path / "messy.bag"
    _messy_bag(path, 5, 64)
    read = []
    with ChunkIndexReader(path) as ours:
        entries = ours.chunk_entries
        monkeypatch.setattr(bag1_raw, "CHUNKS_AT_ONCE", 1)
        monkeypatch.setattr(ours, "chunk_entries", lambda chunk, ids: read.append(chunk) or entries(chunk, ids))
        chunks, firsts = ours.chunk_order({c.id for c in ours.connections})
        first_of = dict(zip(chunks, firsts))
        seen = []
        for _, _, t, _, _ in bag1_raw.messages(ours, ours.connections):
            assert all(first_of[c] <= t for c in read)  # every chunk read so far starts at or before it
            seen.append(t)
    assert len(read) == len(chunks) > 5 and seen == sorted(seen) and len(seen) == 150


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
def test_message_headers_in_any_field_order(tmp_path, monkeypatch, order):
    """rosbag writes a message's header fields as time, conn, op; rosbags (so lio's own logs) as op, conn, time;
    anything else is read field by field: the same messages in every case. Both readers know the first two
    layouts without walking the fields."""
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
    walked = []
    field_walk = bag1_raw._op
    monkeypatch.setattr(bag1_raw, "_op", lambda *a: walked.append(1) or field_walk(*a))
    with Reader(path) as theirs, ChunkIndexReader(path) as ours:
        want = [(c.topic, t, bytes(d)) for c, t, d in theirs.messages(connections=theirs.connections)]
        got = [(topic, t, bytes(d)) for topic, _, t, d, _ in bag1_raw.messages(ours, ours.connections)]
        bulk = bag1_raw.connection_messages(ours, ours.connections, {})
    assert len(walked) == (12 if order == (b"conn", b"op", b"time") else 0)
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
    with Reader(path) as theirs, ChunkIndexReader(path) as ours:
        want = [bytes(d) for _, _, d in theirs.messages()]
        views = [d for *_, d, _ in bag1_raw.messages(ours, ours.connections, {}, views=True)]
        copies = [d for *_, d, _ in bag1_raw.messages(ours, ours.connections, {})]
    assert len(want) == 200 and [bytes(v) for v in views] == want and copies == want
    assert all(type(c) is bytes for c in copies)
    if compression is None:  # an uncompressed chunk is its pooled buffer: views of it, read-only
        assert all(type(v) is memoryview and v.readonly for v in views)
