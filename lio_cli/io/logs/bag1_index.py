"""rosbags' ROS 1 reader with the bag's message index held as int64 columns.

rosbags' ``Reader.open`` turns every index entry of the bag into an ``IndexData`` tuple and sorts each
connection's list with Python comparisons (by time only), before a message is read. ``ColumnIndexReader``
reads the same index records in one numpy call each into columns (time, chunk position, offset in chunk),
stably sorted by time per connection: the order of rosbags' sort. The chunk reader (``bag1_raw``) and the
per-topic spans use the columns; rosbags' ``indexes`` lists (what its own ``messages`` reads) are made from
them on first use of a connection. The rest of the open (bag header, connections, chunk infos and headers)
is rosbags' own.
"""

from __future__ import annotations

from collections.abc import Iterator, Mapping
from itertools import count

import numpy as np
from rosbags.rosbag1.reader import Header, IndexData, Reader, ReaderError, RecordType, read_bytes, read_uint32

_ENTRY = np.dtype([("sec", "<u4"), ("nsec", "<u4"), ("offset", "<u4")])  # one index entry as stored


class _Indexes(Mapping):
    """connection id -> rosbags' sorted list of ``IndexData``, made from the columns on first use."""

    def __init__(self, columns: dict[int, np.ndarray]) -> None:
        self.columns = columns
        self._lists: dict[int, list[IndexData]] = {}

    def __getitem__(self, conn_id: int) -> list[IndexData]:
        found = self._lists.get(conn_id)
        if found is None:
            found = self._lists[conn_id] = [IndexData(*e) for e in zip(*self.columns[conn_id].tolist())]
        return found

    def __iter__(self) -> Iterator[int]:
        return iter(self.columns)

    def __len__(self) -> int:
        return len(self.columns)

    def clear(self) -> None:
        self.columns, self._lists = {}, {}


class ColumnIndexReader(Reader):
    """``rosbags.rosbag1.Reader`` whose ``index_columns`` hold, per connection id, a (3, m) int64 array: record
    time (ns), chunk position and offset in the chunk of each message, in rosbags' index order."""

    def open(self) -> None:
        self._blocks = count()  # index records in the order the open reads them
        self.index_columns: dict[int, np.ndarray] = {}
        super().open()
        if self.indexes:  # (none: a bag without chunks)
            columns = {c.id: _columns(self.indexes[c.id]) for c in self.connections}
            self.connections = [type(c)(*c[0:5], columns[c.id].shape[1], *c[6:]) for c in self.connections]
            self.index_columns = columns
            self.indexes = _Indexes(columns)  # type: ignore[assignment]

    def read_index_data(self, pos: int, indexes: dict) -> None:  # type: ignore[override]
        """One index record (its connection's entries in chunk ``pos``), kept as bytes for ``_columns``; the
        open sorts each connection's records by the order they were read in."""
        assert self.bio
        header = Header.read(self.bio, RecordType.IDXDATA)
        if (ver := header.get_uint32("ver")) != 1:
            raise ReaderError(f"IDXDATA version {ver} is not supported.")
        conn, n = header.get_uint32("conn"), header.get_uint32("count")
        size = read_uint32(self.bio)
        if size != n * _ENTRY.itemsize:
            raise ReaderError(f"IDXDATA of {n} entries has {size} bytes.")
        indexes[conn].append((next(self._blocks), pos, read_bytes(self.bio, size)))


def _columns(blocks: list[tuple[int, int, bytes]]) -> np.ndarray:
    """(3, m) time, chunk position, offset of a connection's index records, stably sorted by time. Built in place
    and sorted only when not in order already (a recorder's records are): a long log's index is megabytes."""
    if not blocks:
        return np.zeros((3, 0), np.int64)
    entries = np.frombuffer(b"".join(b[2] for b in blocks), _ENTRY)
    cols = np.empty((3, len(entries)), np.int64)
    times = cols[0]
    times[:] = entries["sec"]
    times *= 1_000_000_000
    times += entries["nsec"]
    cols[1] = np.repeat(np.array([b[1] for b in blocks], np.int64), [len(b[2]) // _ENTRY.itemsize for b in blocks])
    cols[2] = entries["offset"]
    if len(times) > 1 and not (times[1:] >= times[:-1]).all():
        cols = cols[:, np.argsort(times, kind="stable")]
    return cols


__all__ = ["ColumnIndexReader"]
