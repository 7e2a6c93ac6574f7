"""Static transforms from /tf_static: a frame tree whose chains are resolved on lookup."""

from __future__ import annotations

from collections import deque

import numpy as np

from ..errors import InputError
from ..geometry import inv_pose
from .decode import TF_MESSAGE, decode_tf
from ..model.records import TransformRecord
from .reader import LogReader

TF_STATIC_TOPIC = "/tf_static"


class FrameTree:
    """Undirected graph of rigid transforms; ``lookup(a, b)`` gives ``T_a_b`` through any chain."""

    def __init__(self, transforms: list[TransformRecord] | None = None) -> None:
        self._edges: dict[str, dict[str, np.ndarray]] = {}
        self.transforms: list[TransformRecord] = []
        for tr in transforms or []:
            self.add(tr)

    def add(self, tr: TransformRecord) -> None:
        self.transforms = [t for t in self.transforms if not (t.parent == tr.parent and t.child == tr.child)]
        self.transforms.append(tr)
        self._edges.setdefault(tr.parent, {})[tr.child] = tr.pose  # T_parent_child
        self._edges.setdefault(tr.child, {})[tr.parent] = inv_pose(tr.pose)

    @property
    def frames(self) -> list[str]:
        return sorted(self._edges)

    def path(self, target: str, source: str) -> list[tuple[str, str]] | None:
        """The hops ``[(target, f1), (f1, f2), ..., (fn, source)]`` of the shortest chain, None if unconnected."""
        target, source = target.lstrip("/"), source.lstrip("/")
        if target == source:
            return []
        if target not in self._edges or source not in self._edges:
            return None
        prev: dict[str, str | None] = {target: None}  # breadth-first search from target
        queue = deque([target])
        while queue:
            frame = queue.popleft()
            for nxt in self._edges[frame]:
                if nxt not in prev:
                    prev[nxt] = frame
                    if nxt == source:
                        hops = []
                        while prev[nxt] is not None:
                            hops.append((prev[nxt], nxt))
                            nxt = prev[nxt]
                        return hops[::-1]
                    queue.append(nxt)
        return None

    def hop(self, a: str, b: str) -> np.ndarray:
        """``T_a_b`` of one edge (either direction)."""
        return self._edges[a][b]

    def lookup(self, target: str, source: str) -> np.ndarray | None:
        """``T_target_source`` (maps points from ``source`` into ``target``), or None if unconnected."""
        hops = self.path(target, source)
        if hops is None:
            return None
        T = np.eye(4)
        for a, b in hops:
            T = T @ self._edges[a][b]
        return T


def read_static_frames(log: LogReader, topic: str = TF_STATIC_TOPIC) -> FrameTree:
    """All transforms on /tf_static (usually a handful of latched messages at the start)."""
    tree = FrameTree()
    info = log.topics.get(topic)
    if info is None or info.msgtype != TF_MESSAGE:
        return tree
    seen = 0
    messages = log.messages([topic])
    try:
        for _, _, _, msg in messages:
            for tr in decode_tf(msg):
                tree.add(tr)
            seen += 1
            if seen >= info.count:
                break
    except InputError as err:
        if str(err).startswith(f"{log.path}:"):
            raise
        raise InputError(f"{log.path}: {topic}: {err}") from err
    finally:
        messages.close()  # release the reader's cursor now, not at garbage collection
    return tree
