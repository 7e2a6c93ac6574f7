"""Logs for the fuzz harness: decode with rosbags/mcap, write back through lio's LogWriter, mutate bytes.

Messages are decoded with rosbags (ROS 1 bags, ROS 2 bag folders) or mcap + a rosbags typestore (bare MCAP)
into rosbags message objects and written back in the same format, so a field edit gives a log any ROS tool
reads: only its content is hostile. Byte flips and truncations damage the file itself.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

def decode_log(path: Path, fmt: str) -> tuple[list[tuple[str, str, bool]], list[list]]:
    """([(topic, msgtype, latching)], [[topic, msgtype, record_ns, msg], ...]) in record order."""
    from rosbags.typesys import Stores, get_typestore

    if fmt == "mcap":
        from mcap.reader import make_reader

        ts = get_typestore(Stores.ROS2_HUMBLE)
        conns, msgs = {}, []
        with path.open("rb") as f:
            for schema, channel, m in make_reader(f).iter_messages(log_time_order=True):
                conns.setdefault(channel.topic, (channel.topic, schema.name, False))
                msgs.append([channel.topic, schema.name, m.log_time, ts.deserialize_cdr(m.data, schema.name)])
        return list(conns.values()), msgs
    from rosbags.highlevel import AnyReader

    store = get_typestore(Stores.ROS1_NOETIC if fmt == "ros1" else Stores.ROS2_HUMBLE)
    with AnyReader([path], default_typestore=store) as r:
        conns = {}
        for c in r.connections:
            latch = bool(getattr(c.ext, "latching", 0)) if fmt == "ros1" else False
            conns.setdefault(c.topic, (c.topic, c.msgtype, latch))
        msgs = [[c.topic, c.msgtype, t, r.deserialize(raw, c.msgtype)] for c, t, raw in r.messages()]
    return list(conns.values()), msgs


def write_log(path: Path, fmt: str, conns: list, msgs: list) -> None:
    from lio_cli.io.logs.writer import LogWriter

    with LogWriter(path, fmt) as w:
        for topic, msgtype, latch in conns:
            w.add_topic(topic, msgtype, latching=latch)
        for topic, _, t_ns, msg in msgs:
            w.write(topic, int(t_ns), msg)


def data_file(log: Path) -> Path:
    """The file holding the messages (a ROS 2 bag folder's storage file)."""
    if log.is_dir():
        return next(p for p in sorted(log.iterdir()) if p.suffix in (".db3", ".mcap"))
    return log


def byte_flip(log: Path, rng: np.random.Generator) -> str:
    target = log / "metadata.yaml" if log.is_dir() and rng.random() < 0.1 else data_file(log)
    buf = bytearray(target.read_bytes())
    n = int(rng.integers(1, 33))
    pos = sorted(int(p) for p in rng.integers(0, len(buf), n))
    for p in pos:
        buf[p] ^= int(rng.integers(1, 256))
    target.write_bytes(bytes(buf))
    shown = ", ".join(map(str, pos[:6])) + (", ..." if n > 6 else "")
    return f"{n} bytes flipped in {target.name} at {shown}"


def truncate(log: Path, rng: np.random.Generator) -> str:
    target = data_file(log)
    size = target.stat().st_size
    new = int(rng.integers(0, size)) if rng.random() < 0.5 else size - int(rng.integers(1, max(2, size // 100)))
    with target.open("r+b") as f:
        f.truncate(new)
    return f"{target.name} truncated from {size} to {new} bytes"
