"""rosbags' ROS 1 reader that does not hold the bag's message index: it is read again chunk by chunk.

rosbags' ``Reader.open`` turns every index entry of the bag into an ``IndexData`` tuple and sorts each
connection's list (by time only, stably) before a message is read: 24 bytes or more a message, for the whole
run. ``ChunkIndexReader`` reads the same index records at open only to keep, per index record (a connection's
entries in one chunk), its connection, chunk, entry count and first and last time (one row of int64s), so the
connections' counts and spans are known. The entries themselves are read again when needed: chunk by chunk as
a stream reaches the chunk (``bag1_raw``), or whole for the connections a caller asks (``columns``: rosbags'
``indexes`` lists, what its own ``messages`` reads, are made from them on first use). The times used to order
the chunks are the index records' own, not the chunk infos'. The rest of the open (bag header, connections,
chunk infos and headers) is rosbags' own.
"""

from __future__ import annotations

import struct
from array import array
from collections.abc import Collection, Iterator, Mapping, Sequence
from itertools import chain, repeat

import numpy as np
from rosbags.rosbag1.reader import (Chunk, ChunkInfo, Header, IndexData, Reader, ReaderError, RecordType, read_bytes,
                                   read_uint32)

_U32 = struct.Struct("<I")
_ENTRY = np.dtype([("sec", "<u4"), ("nsec", "<u4"), ("offset", "<u4")])  # one index entry as stored
ENTRY_BYTES = _ENTRY.itemsize
_REC_CONN, _REC_CHUNK, _REC_COUNT, _REC_FIRST, _REC_LAST = range(5)  # the columns of ``records``


class _Indexes(Mapping):
    """connection id -> rosbags' sorted list of ``IndexData``, made from the index on first use of that
    connection."""

    def __init__(self, reader: ChunkIndexReader) -> None:
        self.reader = reader
        self._lists: dict[int, list[IndexData]] = {}

    def __getitem__(self, conn_id: int) -> list[IndexData]:
        if conn_id not in self._lists:
            if conn_id not in {c.id for c in self.reader.connections}:
                raise KeyError(conn_id)
            (c,) = self.reader.columns([conn_id]).values()
            self._lists[conn_id] = [IndexData(*e) for e in zip(*c.tolist())]
        return self._lists[conn_id]

    def __iter__(self) -> Iterator[int]:
        return iter(c.id for c in self.reader.connections)

    def __len__(self) -> int:
        return len(self.reader.connections)

    def clear(self) -> None:
        self._lists = None


class _ChunkInfos(Sequence):
    """rosbags' ``chunk_infos`` held as int64 arrays (a ``ChunkInfo`` with its dict is about 0.5 kB a chunk, for
    the whole run); each ``ChunkInfo`` is made when asked for."""

    def __init__(self, infos: list[ChunkInfo]) -> None:
        self.cols = np.array([(c.pos, c.start_time, c.end_time) for c in infos], np.int64).reshape(-1, 3).T.copy()
        self.bounds = np.cumsum([0] + [len(c.connection_counts) for c in infos]).tolist()
        self.counts = np.array([kv for c in infos for kv in c.connection_counts.items()], np.int64).reshape(-1, 2)

    def __len__(self) -> int:
        return self.cols.shape[1]

    def __getitem__(self, i):  # type: ignore[override]
        if isinstance(i, slice):
            return [self[k] for k in range(len(self))[i]]
        i = range(len(self))[i]
        pos, start, end = self.cols[:, i].tolist()
        return ChunkInfo(pos, start, end, dict(self.counts[self.bounds[i]:self.bounds[i + 1]].tolist()))

    def records(self, i: int) -> int:
        """How many index records chunk ``i`` has (its connections)."""
        return self.bounds[i + 1] - self.bounds[i]

    def clear(self) -> None:
        self.__init__([])


class _Chunks(Mapping):
    """rosbags' ``chunks`` (chunk position -> ``Chunk``) held as int64 arrays; each ``Chunk`` made when asked for."""

    def __init__(self, chunks: Mapping[int, Chunk]) -> None:
        self.funcs: list = []  # the decompressors, one each
        rows = []
        for pos, c in chunks.items():
            code = next((k for k, f in enumerate(self.funcs) if f is c.decompressor), len(self.funcs))
            if code == len(self.funcs):
                self.funcs.append(c.decompressor)
            rows.append((pos, c.datasize, c.datapos, code))
        self.cols = np.array(rows, np.int64).reshape(-1, 4).T.copy()  # in the order rosbags read them
        self.order = np.argsort(self.cols[0], kind="stable")

    def _find(self, pos: int) -> int:
        k = int(np.searchsorted(self.cols[0], pos, sorter=self.order))
        if k == len(self.order) or self.cols[0, self.order[k]] != pos:
            raise KeyError(pos)
        return int(self.order[k])

    def __getitem__(self, pos: int) -> Chunk:
        _, size, data, code = self.cols[:, self._find(pos)].tolist()
        return Chunk(size, data, self.funcs[code])

    def __setitem__(self, pos: int, chunk: Chunk) -> None:
        """Replace the chunk at ``pos`` (as rosbags' dict allows; the tests count decompressions this way)."""
        k = self._find(pos)
        code = next((j for j, f in enumerate(self.funcs) if f is chunk.decompressor), len(self.funcs))
        if code == len(self.funcs):
            self.funcs.append(chunk.decompressor)
        self.cols[1:, k] = (chunk.datasize, chunk.datapos, code)

    def __contains__(self, pos: object) -> bool:
        try:
            self._find(pos)  # type: ignore[arg-type]
        except (KeyError, TypeError):
            return False
        return True

    def __iter__(self) -> Iterator[int]:
        return iter(self.cols[0].tolist())

    def __len__(self) -> int:
        return self.cols.shape[1]

    def clear(self) -> None:
        self.__init__({})


class ChunkIndexReader(Reader):
    """``rosbags.rosbag1.Reader`` whose index is read again when needed. ``records`` is a (5, r) int64 array, one
    column per index record in the order the open read them: connection id, chunk (its place in
    ``chunk_infos``), entry count, first and last entry time (ns); ``spans`` maps a connection id to the first
    and last time of its entries."""

    def open(self) -> None:
        self._rows = array("q")  # the records' rows as read, flattened
        self._record_chunks: Iterator[int] | None = None
        self._index_ends = array("q")  # per chunk, where its index records end in the file
        self.records = np.zeros((5, 0), np.int64)
        self.spans: dict[int, tuple[int, int]] = {}
        super().open()
        rows, self._rows = np.frombuffer(self._rows, np.int64).reshape(-1, 5).T.copy(), array("q")
        self._record_chunks = None  # (it refers to rosbags' list of chunk infos)
        if self.chunk_infos:  # (none: a bag without chunks)
            self.records = rows
            ids = [c.id for c in self.connections]
            counts = dict.fromkeys(ids, 0)
            for conn in ids:
                mine = rows[:, (rows[_REC_CONN] == conn) & (rows[_REC_COUNT] > 0)]
                if mine.shape[1]:
                    counts[conn] = int(mine[_REC_COUNT].sum())
                    self.spans[conn] = (int(mine[_REC_FIRST].min()), int(mine[_REC_LAST].max()))
            self.connections = [type(c)(*c[0:5], counts[c.id], *c[6:]) for c in self.connections]
            self.indexes = _Indexes(self)  # type: ignore[assignment]
            self.chunk_infos = _ChunkInfos(self.chunk_infos)  # type: ignore[assignment]
            self.chunks = _Chunks(self.chunks)  # type: ignore[assignment]

    # rosbags' own build a ChunkInfo per chunk (per connection and chunk for the count): the same from the arrays
    def _arrays(self, nonempty: bool = True) -> _ChunkInfos | None:
        """The chunk infos as arrays (the bag checked open), or None where rosbags' own answer (no chunk)."""
        infos = self.chunk_infos
        if not isinstance(infos, _ChunkInfos) or (nonempty and not len(infos)):
            return None
        self._check_open()
        return infos

    @property
    def start_time(self) -> int:
        infos = self._arrays()
        return super().start_time if infos is None else int(infos.cols[1].min())

    @property
    def end_time(self) -> int:
        infos = self._arrays()
        return super().end_time if infos is None else int(infos.cols[2].max())

    @property
    def message_count(self) -> int:
        if self._arrays(nonempty=False) is None:
            return super().message_count
        return sum(c.msgcount for c in self.connections)  # the index records' counts, summed at open

    def read_index_data(self, pos: int, indexes: dict) -> None:  # type: ignore[override]
        """One index record (its connection's entries in chunk ``pos``), summarised as a row of ``records``."""
        if self._record_chunks is None:  # the open reads each chunk's records right after it, chunk by chunk
            self._record_chunks = chain.from_iterable(
                repeat(k, len(c.connection_counts)) for k, c in enumerate(self.chunk_infos))
            self._index_ends = array("q", bytes(8 * len(self.chunk_infos)))
        conn, raw = self._index_record()
        chunk = next(self._record_chunks)
        self._index_ends[chunk] = self.bio.tell()  # type: ignore[union-attr]
        if raw:
            times = _times(raw)
            self._rows.extend((conn, chunk, len(times), int(times.min()), int(times.max())))
        else:
            self._rows.extend((conn, chunk, 0, 0, 0))

    def _index_record(self) -> tuple[int, bytes]:
        """The connection and stored entries of the index record at the file's position."""
        assert self.bio
        header = Header.read(self.bio, RecordType.IDXDATA)
        if (ver := header.get_uint32("ver")) != 1:
            raise ReaderError(f"IDXDATA version {ver} is not supported.")
        conn, n = header.get_uint32("conn"), header.get_uint32("count")
        size = read_uint32(self.bio)
        if size != n * _ENTRY.itemsize:
            raise ReaderError(f"IDXDATA of {n} entries has {size} bytes.")
        return conn, read_bytes(self.bio, size)

    def chunk_order(self, conn_ids: Collection[int]) -> tuple[list[int], list[int]]:
        """The chunks holding entries of ``conn_ids`` (their places in ``chunk_infos``), by the first time of
        those entries in each, and those first times."""
        rec = self.records
        mine = rec[:, np.isin(rec[_REC_CONN], list(conn_ids)) & (rec[_REC_COUNT] > 0)]
        first = np.full(len(self.chunk_infos), np.iinfo(np.int64).max, np.int64)
        np.minimum.at(first, mine[_REC_CHUNK], mine[_REC_FIRST])
        chunks = np.unique(mine[_REC_CHUNK])
        chunks = chunks[np.argsort(first[chunks], kind="stable")]
        return chunks.tolist(), first[chunks].tolist()

    def chunk_entries(self, chunk: int, conn_ids: Collection[int]) -> tuple[int, list[tuple[int, bytes]]]:
        """The position of chunk ``chunk`` (its place in ``chunk_infos``) and (connection id, stored entries) of
        its index records for ``conn_ids``, in the order they are stored: one read of the records the open
        checked, their headers' conn and count fields found by name."""
        assert self.bio
        chunk_pos = int(self.chunk_infos.cols[0, chunk])  # type: ignore[attr-defined]
        head = self.chunks[chunk_pos]
        start = head.datapos + head.datasize
        self.bio.seek(start)
        buf = read_bytes(self.bio, self._index_ends[chunk] - start)
        out, pos, unpack = [], 0, _U32.unpack_from
        for _ in range(self.chunk_infos.records(chunk)):  # type: ignore[attr-defined]
            (hlen,) = unpack(buf, pos)
            conn = count = -1
            field, h1 = pos + 4, pos + 4 + hlen
            while field < h1:
                (n,) = unpack(buf, field)
                name = buf[field + 4:field + 9]
                if name == b"conn=":
                    (conn,) = unpack(buf, field + 9)
                elif name == b"count":
                    (count,) = unpack(buf, field + 10)
                field += 4 + n
            (size,) = unpack(buf, h1)
            if count < 0 or conn < 0 or size != count * _ENTRY.itemsize or h1 + 4 + size > len(buf):
                raise ReaderError("Bag index changed since it was opened.")
            if conn in conn_ids and size:
                out.append((conn, buf[h1 + 4:h1 + 4 + size]))
            pos = h1 + 4 + size
        return chunk_pos, out

    def columns(self, conn_ids: Collection[int]) -> dict[int, np.ndarray]:
        """Per connection id of ``conn_ids``, a (3, m) int64 array: record time (ns), chunk position and offset
        in the chunk of each of its messages, in rosbags' index order (stably sorted by time)."""
        wanted = set(conn_ids)
        blocks: dict[int, list[tuple[int, bytes]]] = {c: [] for c in conn_ids}
        for chunk in np.unique(self.records[_REC_CHUNK, np.isin(self.records[_REC_CONN], list(wanted))]).tolist():
            pos, entries = self.chunk_entries(chunk, wanted)
            for conn, raw in entries:
                blocks[conn].append((pos, raw))
        return {c: _columns(b) for c, b in blocks.items()}


def _times(raw: bytes) -> np.ndarray:
    """Record times (ns, int64) of stored index entries."""
    entries = np.frombuffer(raw, _ENTRY)
    times = entries["sec"].astype(np.int64)
    times *= 1_000_000_000
    times += entries["nsec"]
    return times


def entry_columns(raw: bytes, pos: int) -> np.ndarray:
    """(3, m) time, chunk position, offset of the stored entries ``raw`` of the chunk at ``pos``, as stored."""
    entries = np.frombuffer(raw, _ENTRY)
    cols = np.empty((3, len(entries)), np.int64)
    cols[0] = _times(raw)
    cols[1] = pos
    cols[2] = entries["offset"]
    return cols


def _columns(blocks: list[tuple[int, bytes]]) -> np.ndarray:
    """(3, m) time, chunk position, offset of a connection's index records (in the order read), stably sorted by
    time; sorted only when not in order already (a recorder's records are)."""
    if not blocks:
        return np.zeros((3, 0), np.int64)
    cols = np.concatenate([entry_columns(raw, pos) for pos, raw in blocks], axis=1)
    times = cols[0]
    if len(times) > 1 and not (times[1:] >= times[:-1]).all():
        cols = cols[:, np.argsort(times, kind="stable")]
    return cols


__all__ = ["ENTRY_BYTES", "ChunkIndexReader", "entry_columns"]
