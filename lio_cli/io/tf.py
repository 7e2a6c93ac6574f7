"""Static transforms from /tf_static: a frame tree whose chains are resolved on lookup."""

from __future__ import annotations

from collections import deque

import numpy as np

from ..errors import InputError
from ..geometry import inv_pose, so3_log
from .decode import TF_MESSAGE, decode_tf
from ..model.records import TransformRecord
from .reader import LogReader

TF_STATIC_TOPIC = "/tf_static"


# Two chains between the same frames that differ by more than this contradict each other.
CONFLICT_TRANSLATION_M = 1e-3
CONFLICT_ROTATION_RAD = np.radians(0.1)
# A quaternion whose norm is off by more than this is normalised with a warning (rounded URDF values are 1e-4 off).
QUAT_NORM_TOL = 1e-2


class TfConflict(InputError):
    """A lookup that needs an edge of a /tf_static cycle whose chains disagree."""


class FrameTree:
    """Undirected graph of rigid transforms; ``lookup(a, b)`` gives ``T_a_b`` through any chain.

    An edge that closes a cycle whose chains disagree (beyond 1 mm or 0.1 deg) is not added: it is recorded in
    ``conflicts``, and a lookup through any edge of that cycle raises ``TfConflict`` naming the frames and how
    far apart the chains are. ``warnings``: what was repaired on the way (non-unit quaternions)."""

    def __init__(self, transforms: list[TransformRecord] | None = None, where: str = "/tf_static") -> None:
        self._edges: dict[str, dict[str, np.ndarray]] = {}
        self.transforms: list[TransformRecord] = []
        self.where = where
        self.conflicts: list[dict] = []
        self._conflicted: dict[frozenset, str] = {}  # edge -> the message a lookup through it raises
        self.warnings: list[str] = []
        for tr in transforms or []:
            self.add(tr)

    def add(self, tr: TransformRecord) -> None:
        republished = any(t.parent == tr.parent and t.child == tr.child for t in self.transforms)
        self.transforms = [t for t in self.transforms if not (t.parent == tr.parent and t.child == tr.child)]
        if republished:  # the same edge again (a latched re-publication): the latest value holds
            self._edges.get(tr.parent, {}).pop(tr.child, None)
            self._edges.get(tr.child, {}).pop(tr.parent, None)
        hops = self.path(tr.parent, tr.child)
        if hops is not None and hops:
            T = self.lookup_hops(hops)
            dt = float(np.linalg.norm(T[:3, 3] - tr.pose[:3, 3]))
            da = float(np.linalg.norm(so3_log(T[:3, :3].T @ tr.pose[:3, :3])))
            if dt > CONFLICT_TRANSLATION_M or da > CONFLICT_ROTATION_RAD:
                self._conflict(tr, hops, dt, da)
                self.transforms.append(tr)  # listed (lio info shows it), never used
                return
        self.transforms.append(tr)
        self._edges.setdefault(tr.parent, {})[tr.child] = tr.pose  # T_parent_child
        self._edges.setdefault(tr.child, {})[tr.parent] = inv_pose(tr.pose)

    def _declared(self, a: str, b: str) -> str:
        """An edge as /tf_static declares it (parent -> child)."""
        return f"{a} -> {b}" if any(t.parent == a and t.child == b for t in self.transforms) else f"{b} -> {a}"

    def _conflict(self, tr: TransformRecord, hops: list[tuple[str, str]], dt: float, da: float) -> None:
        chain = ", ".join(self._declared(a, b) for a, b in hops)
        message = (f"{self.where} contradicts itself: {tr.parent} -> {tr.child} disagrees with {chain} by "
                   f"{dt:.3f} m and {np.degrees(da):.2f} deg")
        self.conflicts.append({"edge": [tr.parent, tr.child], "chain": chain, "distance_m": round(dt, 6),
                               "angle_deg": round(float(np.degrees(da)), 4), "message": message})
        for a, b in [*hops, (tr.parent, tr.child)]:
            self._conflicted.setdefault(frozenset((a, b)), message)

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

    def lookup_hops(self, hops: list[tuple[str, str]]) -> np.ndarray:
        T = np.eye(4)
        for a, b in hops:
            T = T @ self._edges[a][b]
        return T

    def lookup(self, target: str, source: str) -> np.ndarray | None:
        """``T_target_source`` (maps points from ``source`` into ``target``), or None if unconnected.

        ``TfConflict`` when the chain runs through an edge of a cycle whose chains disagree."""
        hops = self.path(target, source)
        if hops is None:
            return None
        for a, b in hops:
            message = self._conflicted.get(frozenset((a, b)))
            if message is not None:
                raise TfConflict(f"{message}; give the extrinsics with --calib (or a --base-frame whose chains "
                                 "avoid these frames)")
        return self.lookup_hops(hops)


def read_static_frames(log: LogReader, topic: str = TF_STATIC_TOPIC) -> FrameTree:
    """All transforms on /tf_static (usually a handful of latched messages at the start)."""
    tree = FrameTree(where=f"{log.path}: {topic}")
    info = log.topics.get(topic)
    if info is None or info.msgtype != TF_MESSAGE:
        return tree
    seen = 0
    messages = log.messages([topic])
    try:
        for _, _, _, msg in messages:
            for ts, tr in zip(msg.transforms, decode_tf(msg)):
                _check_quaternion(tree, ts, topic)
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


def _check_quaternion(tree: FrameTree, ts, topic: str) -> None:
    """Warn (once per edge) about a quaternion far from unit norm; small deviations are normalised silently."""
    q = ts.transform.rotation
    norm = float(np.sqrt(q.x * q.x + q.y * q.y + q.z * q.z + q.w * q.w))
    if abs(norm - 1.0) > QUAT_NORM_TOL:
        parent, child = ts.header.frame_id.lstrip("/"), ts.child_frame_id.lstrip("/")
        text = (f"{topic}: {parent} -> {child} has a quaternion of norm {norm:.4g} "
                f"(xyzw {q.x:.4g}, {q.y:.4g}, {q.z:.4g}, {q.w:.4g}); normalised")
        if not any(w.startswith(f"{topic}: {parent} -> {child} ") for w in tree.warnings):
            tree.warnings.append(text)
