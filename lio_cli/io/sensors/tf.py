"""Static transforms from /tf_static: a frame tree whose chains are resolved on lookup."""

from __future__ import annotations

from collections import deque

import numpy as np

from ...errors import InputError
from ...geometry import inv_pose, so3_log
from ..messages.decode import TF_MESSAGE, decode_tf
from ...model.records import TransformRecord
from ..logs.base import LogReader

TF_STATIC_TOPIC = "/tf_static"
TF_TOPIC = "/tf"
_TF_MESSAGES = 2000  # /tf messages looked at for mountings published there
_MOVING_FRAMES = {"map", "odom", "world", "earth", "utm", "gps", "enu"}


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
        self.tf_edges: set[frozenset] = set()  # edges taken from /tf (``_add_fixed_tf``), not /tf_static
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

    def root(self, frame: str) -> str | None:
        """The one frame of ``frame``'s tree that is no transform's child (Ouster's os_sensor above os_lidar and
        os_imu), or None when ``frame`` is not in a tree or the tree has no single root."""
        frame = frame.lstrip("/")
        if frame not in self._edges:
            return None
        seen, todo = {frame}, deque([frame])
        while todo:
            for nxt in self._edges[todo.popleft()]:
                if nxt not in seen:
                    seen.add(nxt)
                    todo.append(nxt)
        children = {t.child for t in self.transforms}
        roots = sorted(seen - children)
        return roots[0] if len(roots) == 1 else None

    def source(self, target: str, source: str) -> str:
        """Where the chain ``target`` -> ``source`` comes from: /tf_static, or /tf when an edge of it does."""
        hops = self.path(target, source) or []
        return TF_TOPIC if any(frozenset(h) in self.tf_edges for h in hops) else TF_STATIC_TOPIC

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
    if info is not None and info.msgtype == TF_MESSAGE:
        _read_all(log, topic, info.count, tree)
    if topic == TF_STATIC_TOPIC:
        _add_fixed_tf(log, tree)
    return tree


def _read_all(log: LogReader, topic: str, count: int, tree: FrameTree) -> None:
    seen = 0
    messages = log.messages([topic], fast=True)  # TFMessage parsed from its bytes (rawmsg.parse_tf)
    try:
        for _, _, _, msg in messages:
            for ts, tr in zip(msg.transforms, decode_tf(msg)):
                _check_quaternion(tree, ts, topic)
                tree.add(tr)
            seen += 1
            if seen >= count:
                break
    except InputError as err:
        if str(err).startswith(f"{log.path}:"):
            raise
        raise InputError(f"{log.path}: {topic}: {err}") from err
    finally:
        messages.close()  # release the reader's cursor now, not at garbage collection


def _add_fixed_tf(log: LogReader, tree: FrameTree) -> None:
    """Edges that /tf repeats unchanged over its first messages, where /tf_static has no chain between their
    frames: a mounting published as /tf (a tf1 static_transform_publisher, an old robot_state_publisher, a
    recording that missed the latched /tf_static) is a mounting all the same. Odometry frames (map, odom,
    world...) move however still they look at the start, so they stay out; each edge taken is a warning."""
    info = log.topics.get(TF_TOPIC)
    if info is None or info.msgtype != TF_MESSAGE or info.count == 0:
        return
    seen: dict[tuple[str, str], tuple[np.ndarray, int]] = {}
    messages = log.messages([TF_TOPIC], fast=True)
    try:
        for n, (_, _, _, msg) in enumerate(messages):
            for tr in decode_tf(msg):
                key = (tr.parent, tr.child)
                first = seen.get(key)
                if first is None:
                    seen[key] = (tr.pose, 1)
                elif first[1] > 0:  # -1: it moved
                    same = np.array_equal(first[0], tr.pose)
                    seen[key] = (first[0], first[1] + 1 if same else -1)
            if n + 1 >= _TF_MESSAGES:
                break
    except InputError:
        return  # a damaged /tf is no mounting: nothing taken from it
    finally:
        messages.close()
    for (parent, child), (pose, count) in seen.items():
        if count < 2 or _moving_frame(parent) or _moving_frame(child) or tree.path(parent, child) is not None:
            continue
        tree.add(TransformRecord(0, parent, child, pose))
        tree.tf_edges.add(frozenset((parent, child)))
        tree.warnings.append(f"{TF_TOPIC}: {parent} -> {child} taken as a mounting (the same over its {count} "
                             f"messages among the first {_TF_MESSAGES} of {TF_TOPIC}; {TF_STATIC_TOPIC} has no chain "
                             "between them)")


def _moving_frame(name: str) -> bool:
    low = name.lower()
    return low in _MOVING_FRAMES or low.endswith("odom") or low.endswith("_map")


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
