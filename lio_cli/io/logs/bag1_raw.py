"""Serialised messages of a few topics of one ROS 1 bag, straight from its chunks.

rosbags' ``Reader.messages`` parses every record header into a dict of fields and merges the per-connection
indexes one entry at a time. Here the same index entries (read a few chunks' at a time as the stream reaches
them: ``bag1_index``) are put in the same order (by record time; on equal times connection by connection in the
order asked, each in its index order: what ``heapq.merge`` yields) and each record is sliced out of its
decompressed chunk with ``struct``. Same messages, same order, same bytes; anything unexpected raises (the
caller reports the log as damaged).
"""

from __future__ import annotations

import struct
from collections.abc import Callable, Iterator
from itertools import chain

import numpy as np

from ...buffers import ArrayPool
from .bag1_index import ENTRY_BYTES, entry_columns

_U32 = struct.Struct("<I")
_OP_MSGDATA, _OP_CONNECTION = 2, 7
_TIME, _CONN = b"\x0d\x00\x00\x00time=", b"\x09\x00\x00\x00conn="  # a message header's first two fields
_OP_FIRST = b"\x04\x00\x00\x00op="  # the first field of rosbags' (and so lio's own) message headers: op, conn, time
_OP_LEN = len(_OP_FIRST)
CHUNKS_AT_ONCE = 8  # chunks whose index is read and merged in one go (a few hundred entries on a walk)
KEEP_CHUNKS = 3  # decompressed chunks kept: record times of neighbouring chunks overlap
_POOL = ArrayPool(2 * KEEP_CHUNKS)  # chunks as read, each a read-only view of a pooled buffer


def _op(buf: bytes, start: int, end: int) -> int:
    """The ``op`` field of the record header in ``buf[start:end]``."""
    unpack = _U32.unpack_from
    pos = start
    while pos < end:
        (n,) = unpack(buf, pos)
        pos += 4
        if buf[pos:pos + 3] == b"op=":
            return buf[pos + 3]
        pos += n
    raise ValueError("record header without op")


def _chunk(reader, pos: int, chunks: dict[int, bytes]) -> bytes | memoryview:
    """The decompressed chunk at ``pos``, from ``chunks`` (the last ``KEEP_CHUNKS`` decompressed) or the file.
    Read into a pooled buffer: an uncompressed chunk (which decompresses to itself) is a view of it."""
    buf = chunks.get(pos)
    if buf is None:
        chunk = reader.chunks[pos]
        reader.bio.seek(chunk.datapos)
        raw = memoryview(_POOL.empty(chunk.datasize, np.uint8))
        if reader.bio.readinto(raw) != chunk.datasize:
            raise ValueError("chunk truncated")
        buf = chunks[pos] = chunk.decompressor(raw.toreadonly())
        if len(chunks) > KEEP_CHUNKS:
            del chunks[next(iter(chunks))]  # the oldest decompressed
    return buf


def _entries(reader, connections: list) -> Iterator[Iterator[tuple[int, int, int, int]]]:
    """Blocks of (time, chunk position, offset in chunk, index of the connection in ``connections``) of every
    index entry in the order rosbags' ``heapq.merge`` of its index lists gives (its entries compare by time
    only: equal times come connection by connection in the order asked, each in its index order, which is the
    order the open reads the index records in, stably sorted by time), i.e. a stable sort by time.

    The index is read chunk by chunk (``bag1_index``; ``CHUNKS_AT_ONCE`` at a time), the chunks in the order of
    their entries' first times: once chunks are read, every entry earlier than the next chunk's first time is
    known, and those are sorted (by time, connection, read order) and handed on, in Python values; the rest wait
    for the next chunks. Chunks whose times overlap are so merged, and the index held is about the chunks the
    stream is in."""
    ids = [c.id for c in connections]
    places: dict[int, list[int]] = {}  # connection id -> its places in ``connections`` (asked twice: yielded twice)
    for k, conn_id in enumerate(ids):
        places.setdefault(conn_id, []).append(k)
    chunks, firsts = reader.chunk_order(places)
    held = np.zeros((5, 0), np.int64)  # time, connection's place, read order (chunk, entry), chunk position, offset
    for i in range(0, len(chunks), CHUNKS_AT_ONCE):
        raws, ks, pos, seq = [], [], [], []
        for chunk in chunks[i:i + CHUNKS_AT_ONCE]:
            n = 0
            chunk_pos, entries = reader.chunk_entries(chunk, places)
            for conn_id, raw in entries:
                m = len(raw) // ENTRY_BYTES
                for k in places[conn_id]:
                    raws.append(raw)
                    ks.append(k)
                    pos.append(chunk_pos)
                    seq.append((chunk << 32) + n)
                n += m
        counts = [len(r) // ENTRY_BYTES for r in raws]
        cols = entry_columns(b"".join(raws), 0)
        part = np.empty((5, cols.shape[1]), np.int64)
        part[0], part[4] = cols[0], cols[2]
        part[1] = np.repeat(np.array(ks, np.int64), counts)
        part[3] = np.repeat(np.array(pos, np.int64), counts)
        # read order: each record's first entry's number, less the record's place in ``part``, plus the place
        part[2] = np.repeat(np.array(seq, np.int64) - np.cumsum([0] + counts[:-1]), counts) + np.arange(cols.shape[1])
        block = np.concatenate((held, part), axis=1) if held.shape[1] else part
        nxt = i + CHUNKS_AT_ONCE
        ready = block[0] < firsts[nxt] if nxt < len(chunks) else np.ones(block.shape[1], bool)
        out, held = block[:, ready], block[:, ~ready]
        if out.shape[1]:
            out = out[:, np.lexsort((out[2], out[1], out[0]))]
            yield zip(out[0].tolist(), out[3].tolist(), out[4].tolist(), out[1].tolist())


def messages(reader, connections: list, chunks: dict[int, bytes] | None = None, views: bool = False
             ) -> Iterator[tuple[str, str, int, bytes | memoryview, object]]:
    """(topic, msgtype, record time ns, serialised message, connection) of ``connections`` (rosbags
    connections of the one ROS 1 ``reader``, a ``bag1_index.ChunkIndexReader``), in the order rosbags'
    ``reader.messages(connections=...)`` yields them. ``views``: a message may be a read-only view of its chunk
    (no copy; it keeps the chunk's buffer from reuse while it lives), else it is bytes.

    ``chunks`` (chunk position -> decompressed bytes, the last ``KEEP_CHUNKS``) may be kept by the caller
    across calls: messages in record-time order go back and forth between neighbouring chunks whose times
    overlap, and a peek at a topic's first messages opens the chunks the full read opens next; each is
    decompressed once (bz2 is most of the reading time)."""
    unpack = _U32.unpack_from
    chunk_pos, buf = -1, b""
    chunks = {} if chunks is None else chunks
    topics, types = [c.topic for c in connections], [c.msgtype for c in connections]
    for t_ns, pos_c, offset, k in chain.from_iterable(_entries(reader, connections)):
        if pos_c != chunk_pos:
            buf = _chunk(reader, pos_c, chunks)
            chunk_pos = pos_c
        pos = offset
        while True:
            (hlen,) = unpack(buf, pos)
            h0, h1 = pos + 4, pos + 4 + hlen
            if buf[h0 + 34:h0 + 37] == b"op=" and buf[h0:h0 + 9] == _TIME and buf[h0 + 17:h0 + 26] == _CONN \
                    and h0 + 37 < h1:
                op = buf[h0 + 37]  # time, conn, op as rosbag writes them: what _op finds, without its loop
            elif buf[h0:h0 + _OP_LEN] == _OP_FIRST and h0 + _OP_LEN < h1:
                op = buf[h0 + _OP_LEN]  # op first, as rosbags writes them
            else:
                op = _op(buf, h0, h1)
            (dlen,) = unpack(buf, h1)
            d0 = h1 + 4
            if op != _OP_CONNECTION:
                break
            pos = d0 + dlen
        if op != _OP_MSGDATA or d0 + dlen > len(buf):
            raise ValueError("expected message data in the bag chunk")
        data = buf[d0:d0 + dlen]
        yield topics[k], types[k], t_ns, data if views or type(data) is bytes else bytes(data), connections[k]


def connection_messages(reader, connections: list, chunks: dict[int, bytes] | None = None,
                        progress: Callable[[int], None] | None = None) -> list[list[bytes]] | None:
    """Per connection, its serialised messages in index order (what ``messages`` yields of it), sliced
    chunk by chunk with the record headers checked for all of a chunk's entries at once (not one message at a
    time). None when a record is not a message-data record of one of the header layouts ``_LAYOUTS``:
    ``messages`` reads those. Each chunk is decompressed once; ``progress`` gets the messages read
    after each."""
    by_id = reader.columns({c.id for c in connections})
    cols = [by_id[c.id] for c in connections]
    parts: list[list] = [[None] * c.shape[1] for c in cols]
    by_chunk: dict[int, list[tuple[int, np.ndarray]]] = {}  # chunk position -> (connection, its entries there)
    for ci, c in enumerate(cols):
        order = np.argsort(c[1], kind="stable")  # grouped once, in index order within a chunk
        pos, first = np.unique(c[1][order], return_index=True)
        for p, sel in zip(pos.tolist(), np.split(order, first[1:])):
            by_chunk.setdefault(p, []).append((ci, sel))
    chunks = {} if chunks is None else chunks
    done = 0
    for pos in sorted(by_chunk):
        buf = _chunk(reader, pos, chunks)
        for ci, sel in by_chunk[pos]:
            spans = _data_spans(buf, cols[ci][2, sel])
            if spans is None:
                return None
            out = parts[ci]
            for j, a, b in zip(sel.tolist(), *spans):
                out[j] = bytes(buf[a:b])  # a copy: a view would keep the chunk's whole buffer
            done += len(sel)
        if progress is not None:
            progress(done)
    return parts


def _layout(head: bytes, variable: tuple[slice, ...] = ()) -> tuple[np.ndarray, np.ndarray]:
    """A header's leading bytes up to its op value, and which of them are fixed (not a time or conn value)."""
    fixed = np.ones(len(head), bool)
    for v in variable:
        fixed[v] = False
    return np.frombuffer(head, np.uint8), fixed


# the two layouts ``messages`` reads without its loop: rosbag's time, conn, op; rosbags' (lio's own) op first
_LAYOUTS = (_layout(_TIME + b"\0" * 8 + _CONN + b"\0" * 4 + _OP_FIRST, (slice(9, 17), slice(26, 30))),
            _layout(_OP_FIRST))


def _data_spans(buf: bytes, offsets: np.ndarray) -> tuple[list[int], list[int]] | None:
    """(start, end) of the message data of the records at ``offsets`` in ``buf``, or None unless every one is a
    message-data record whose header has one of ``_LAYOUTS`` (what ``messages`` reads without its loop)."""
    n = len(buf)
    u8 = np.frombuffer(buf, np.uint8)
    for template, fixed in _LAYOUTS:
        k = len(template) + 1
        if int(offsets.max()) + 4 + k > n:
            continue
        head = u8[offsets[:, None] + np.arange(4 + k)]
        hlen = head[:, :4].copy().view("<u4")[:, 0].astype(np.int64)
        h = head[:, 4:]
        if (h[:, :-1] == template)[:, fixed].all() and (h[:, -1] == _OP_MSGDATA).all() and (hlen >= k).all():
            break
    else:
        return None
    h1 = offsets + 4 + hlen
    if int(h1.max()) + 4 > n:
        return None
    d0 = h1 + 4
    d1 = d0 + u8[h1[:, None] + np.arange(4)].copy().view("<u4")[:, 0]
    if int(d1.max()) > n:
        return None
    return d0.tolist(), d1.tolist()
