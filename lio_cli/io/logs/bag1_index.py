"""rosbags' ROS 1 reader with the bag's message index held as int64 columns.

rosbags' ``Reader.open`` turns every index entry of the bag into an ``IndexData`` tuple and sorts each
connection's list with Python comparisons (by time only), before a message is read. ``ColumnIndexReader``
reads the same index records in one numpy call each into columns (time, chunk position, offset in chunk),
stably sorted by time per connection: the order of rosbags' sort. The chunk reader (``bag1_raw``) and the
per-topic spans use the columns; rosbags' ``indexes`` lists (what its own ``messages`` reads) are made from
them on first use of a connection. The rest of the open (bag header, connections, chunk infos and headers)
is rosbags' own.

``Bag1Reader`` is rosbags' ``AnyReader`` for ROS 1 bags alone (the same connections, typestore, checks and
messages), without the import of ``rosbags.highlevel``, which loads the ROS 2 reader and its storages too.
"""

from __future__ import annotations

from collections.abc import Iterator, Mapping
from contextlib import ExitStack, suppress
from heapq import merge
from itertools import count, groupby

import numpy as np
from rosbags.interfaces import MessageDefinitionFormat
from rosbags.rosbag1.reader import Header, IndexData, Reader, ReaderError, RecordType, read_bytes, read_uint32
from rosbags.serde import SerdeError
from rosbags.typesys import Stores, TypesysError, get_types_from_msg, get_typestore

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
    """(3, m) time, chunk position, offset of a connection's index records, stably sorted by time."""
    if not blocks:
        return np.zeros((3, 0), np.int64)
    entries = np.frombuffer(b"".join(b[2] for b in blocks), _ENTRY)
    times = entries["sec"].astype(np.int64) * 1_000_000_000 + entries["nsec"]
    chunk_pos = np.repeat(np.array([b[1] for b in blocks], np.int64), [len(b[2]) // _ENTRY.itemsize for b in blocks])
    cols = np.stack([times, chunk_pos, entries["offset"].astype(np.int64)])
    return cols[:, np.argsort(times, kind="stable")]


class Bag1AnyReaderError(Exception):
    """What ``AnyReaderError`` is to ``AnyReader``: a bag that cannot be opened or a message not decoded."""


class Bag1Reader:
    """rosbags' ``AnyReader`` over ROS 1 bags (``ColumnIndexReader`` each): ``open``, ``connections``,
    ``typestore``, ``deserialize``, ``messages``, ``close``, the span and count, with its errors' texts."""

    def __init__(self, paths: list, default_typestore=None) -> None:
        if not paths:
            raise Bag1AnyReaderError("Must call with at least one path.")
        if missing := [x for x in paths if not x.exists()]:
            raise FileNotFoundError(f"The following paths are missing: {missing!r}")
        self.paths, self.default_typestore = paths, default_typestore
        self.stack: ExitStack | None = None
        self.connections: list = []
        self.typestore = get_typestore(Stores.EMPTY)
        try:
            self.readers = [ColumnIndexReader(x) for x in paths]
        except ReaderError as err:
            raise Bag1AnyReaderError(*err.args) from None

    def open(self) -> None:
        if self.stack:
            raise Bag1AnyReaderError("AnyReader is already open.")
        self.stack = ExitStack()
        try:
            self._open()
        except BaseException as err:
            with suppress(Exception):
                self.close()
            if isinstance(err, (ReaderError, TypesysError)):
                raise Bag1AnyReaderError(*err.args) from None
            raise

    def _open(self) -> None:
        """The readers opened, the typestore made of the stored definitions and checked against their md5s."""
        for reader in self.readers:
            self.stack.enter_context(reader)
        typs: dict = {}
        digests: dict[str, str] = {}
        connections = [y for x in self.readers for y in x.connections]
        if connections:
            definitions = [x for x in connections if x.msgdef.format != MessageDefinitionFormat.NONE]
            if definitions:
                for connection in definitions:  # a ROS 1 bag's are all msg
                    typs.update(get_types_from_msg(connection.msgdef.data, connection.msgtype))
                    if connection.digest:
                        digests[connection.msgtype] = connection.digest
            elif self.default_typestore:
                typs.update(self.default_typestore.fielddefs)
            else:
                raise Bag1AnyReaderError("Bag contains no type definitions. "
                                         "Instantiate AnyReader with a default_typestore argument.")
        typestore = get_typestore(Stores.EMPTY)
        typestore.register(typs)
        for msgtype, digest in digests.items():
            if (have := typestore.generate_msgdef(msgtype)[1]) != digest:
                raise Bag1AnyReaderError(f"Message type {msgtype!r} hash mismatch {have} != {digest}")
        self.connections = connections
        self.typestore = typestore

    def close(self) -> None:
        if not self.stack:
            raise Bag1AnyReaderError("AnyReader is not open.")
        stack, self.stack = self.stack, None
        self.connections.clear()
        self.typestore = get_typestore(Stores.EMPTY)
        stack.close()

    def deserialize(self, rawdata: bytes, typ: str) -> object:
        try:
            return self.typestore.deserialize_ros1(rawdata, typ)
        except SerdeError as err:
            raise Bag1AnyReaderError(*err.args) from None

    @property
    def start_time(self) -> int:
        return min(x.start_time for x in self.readers)

    @property
    def end_time(self) -> int:
        return max(x.end_time for x in self.readers)

    @property
    def message_count(self) -> int:
        return sum(x.message_count for x in self.readers)

    def messages(self, connections=()):
        """(connection, record time ns, bytes) of ``connections`` (all if empty) over the bags in time order."""
        if connections:
            generators = [reader.messages(connections=list(conns)) for reader, conns in
                          groupby(sorted(connections, key=lambda x: id(x.owner)), key=lambda x: x.owner)]
        else:
            generators = [reader.messages() for reader in self.readers]
        yield from merge(*generators, key=lambda x: x[1])


__all__ = ["Bag1Reader", "Bag1AnyReaderError", "ColumnIndexReader"]
