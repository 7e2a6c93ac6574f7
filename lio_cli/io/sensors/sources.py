"""Trajectory sources: what a user names on the command line, read into a ``Trajectory``.

A TUM or KITTI file, or a topic of a log (``LOG:/topic``, ``LOG#/topic``), or a chain of /tf and /tf_static
(``LOG:tf:parent.child``). A NavSatFix topic becomes a position-only trajectory in a local ENU frame
(``io.gps``). Every problem is an ``InputError`` naming the file.
"""

from __future__ import annotations

import sys
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from ...errors import InputError
from ...geometry import interpolate_poses, inv_pose
from ...model.records import TransformRecord
from ...model.trajectory import Trajectory
from ..logs.detect import looks_like_log
from .tf import FrameTree
from ..files.trajectory import read_kitti, read_text, read_times, read_tum, sniff_columns

if TYPE_CHECKING:
    from ...geodesy import EnuFrame


def split_source(spec: str) -> tuple[str, str | None]:
    """(path, topic spec or None) of ``LOG:/topic``, ``LOG#topic``, ``LOG:tf:a.b``, or a plain path."""
    if Path(spec).exists():
        return spec, None
    if "#" in spec:
        path, _, topic = spec.rpartition("#")
        return path, topic
    for marker in (":/", ":tf:"):
        pos = spec.find(marker)
        if pos > 0:
            return spec[:pos], spec[pos + 1:]
    return spec, None


def load_trajectory(
    spec: str,
    *,
    topic: str | None = None,
    times: str | Path | None = None,
    rate_hz: float | None = None,
    stamp_unit: str = "s",
    origin: EnuFrame | None = None,
    stamp_options: bool = False,
) -> Trajectory:
    """Read the trajectory ``spec`` names (file or ``LOG:/topic``); ``topic`` picks one in a bare log path.

    ``origin``: the ENU origin of a NavSatFix topic (default: its first valid fix). ``stamp_options``: the
    command offers --times/--rate for KITTI poses (evaluate); the others need a TUM file.
    """
    if spec == "-":  # standard input: `lio odom LOG -o - | lio evaluate GT -`
        if sys.stdin is None or sys.stdin.isatty():
            raise InputError("-: standard input is a terminal; pipe a TUM or KITTI trajectory into it "
                             "(lio odom LOG -o - | lio evaluate GT -)")
        path, text = Path("-"), sys.stdin.read()
    else:
        path_text, topic_spec = split_source(spec)
        path = Path(path_text)
        if not path.exists():
            raise InputError(f"{path}: no such file or folder")
        if topic_spec is None and looks_like_log(path):
            return read_log_trajectory(path, topic, required_kind="gt", origin=origin)
        if topic_spec is not None:
            return read_log_trajectory(path, topic_spec, origin=origin)
        text = read_text(path)  # once: a pipe (`--gt <(...)`) gives its bytes only once
    cols = sniff_columns(path, text)
    if cols == 12:
        poses = read_kitti(path, text)
        if times is not None:
            stamps = read_times(times)
            if len(stamps) != len(poses):
                raise InputError(
                    f"{path}: {len(poses)} KITTI poses but {times} holds {len(stamps)} stamps; "
                    f"lengths must match line by line"
                )
        elif rate_hz is not None:
            if not rate_hz > 0:
                raise InputError(f"--rate must be positive, got {rate_hz}")
            stamps = np.round(np.arange(len(poses)) * (1e9 / rate_hz)).astype(np.int64)
        else:
            raise InputError(f"{path}: KITTI poses carry no stamps; " + (
                "give --times FILE (KITTI times.txt) or --rate HZ" if stamp_options else
                "give a TUM file (stamp tx ty tz qx qy qz qw per line, as lio odom writes)"))
        return Trajectory(stamps, poses, str(path), "kitti")
    if cols == 8:
        stamps, poses = read_tum(path, stamp_unit, text)
        return Trajectory(stamps, poses, str(path), "tum")
    raise InputError(
        f"{path}: first line has {cols} values; expected 8 (TUM: stamp tx ty tz qx qy qz qw) or 12 (KITTI 3x4 pose)"
    )


def load_ground_truth(log: str | Path, gt: str) -> Trajectory:
    """A run's ground truth as ``lio odom --gt`` takes it: a file, or a topic of ``log`` (``/name`` that is no
    file). An absolute path into an existing folder that is neither a file nor a topic of the log is reported
    as the missing file it most likely is, not as a missing topic."""
    if not gt.startswith("/") or Path(gt).exists():
        return load_trajectory(gt)
    try:
        return load_trajectory(f"{log}:{gt}")
    except InputError as err:
        parent = Path(gt).parent
        if parent == Path("/") or not parent.is_dir() or _has_topic(Path(log), gt):
            raise
        raise InputError(f"{gt}: no such file, nor a topic of {log}") from err


def _has_topic(log: Path, topic: str) -> bool:
    from ..logs.reader import open_log

    try:
        with open_log(log) as reader:
            return topic in reader.topics
    except InputError:
        return False


def read_log_trajectory(path: Path, topic_spec: str | None, required_kind: str = "gt",
                        origin: EnuFrame | None = None) -> Trajectory:
    """Poses of one topic of a log (Odometry, PoseStamped, TransformStamped), a TF chain ``tf:a.b``, or the
    ENU positions of a NavSatFix topic (named, or the log's only one when it has no pose topic)."""
    from ..messages.decode import NAVSATFIX
    from ..logs.reader import open_log
    from .stream import SensorStream
    from .topics import select_topic

    with open_log(path) as log:
        if topic_spec is not None and topic_spec.startswith("tf:"):
            return _read_tf_chain(log, path, topic_spec[3:])
        info = log.topics.get(topic_spec) if topic_spec is not None else None
        gps_topic = topic_spec if info is not None and info.msgtype == NAVSATFIX else None
        if topic_spec is None and select_topic(log, required_kind, None, required=False) is None:
            gps = sorted(t for t, i in log.topics.items() if i.msgtype == NAVSATFIX and i.count > 0)
            if len(gps) > 1:
                raise InputError(f"{path}: no ground-truth pose topic and several GPS topics ({', '.join(gps)}); "
                                 f"name one as LOG:/topic")
            gps_topic = gps[0] if gps else None
        if gps_topic is not None:
            return _read_gps(log, path, select_topic(log, "gps", gps_topic), origin)
        topic = select_topic(log, required_kind, topic_spec)
        stamps, poses = [], []
        for rec in SensorStream(log, {"gt": topic}, strict=True):
            stamps.append(rec.stamp_ns)
            poses.append(rec.data.pose)
    if not poses:
        raise InputError(f"{path}: topic {topic} holds no messages")
    return Trajectory(np.asarray(stamps, dtype=np.int64), np.asarray(poses), f"{path}:{topic}", "topic")


def _read_gps(log, path: Path, topic: str, origin: EnuFrame | None) -> Trajectory:
    from .gps import gps_poses, read_gps_track

    track = read_gps_track(log, topic, origin)
    return Trajectory(track.stamps_ns, gps_poses(track), f"{path}:{topic}", "gps", gps=track)


def _read_tf_chain(log, path: Path, chain: str) -> Trajectory:
    """``T_parent_child`` over time from /tf (dynamic) and /tf_static, composing any chain between them.

    The output stamps are those of the busiest dynamic edge on the chain; other dynamic edges are interpolated
    there, and stamps outside any dynamic edge's span are dropped.
    """
    from ..messages.decode import TF_MESSAGE, decode_tf

    edges: dict[tuple[str, str], list[tuple[int, np.ndarray]]] = {}
    static: dict[tuple[str, str], np.ndarray] = {}
    topics = [t for t in ("/tf", "/tf_static") if t in log.topics and log.topics[t].msgtype == TF_MESSAGE]
    if not topics:
        raise InputError(f"{path}: no /tf or /tf_static topic (tf2_msgs/TFMessage) to read tf:{chain} from")
    for topic, _, _, msg in log.messages(topics):
        for tr in decode_tf(msg):
            if topic == "/tf_static":
                static[(tr.parent, tr.child)] = tr.pose
            else:
                edges.setdefault((tr.parent, tr.child), []).append((tr.stamp_ns, tr.pose))
    frames = {f for e in list(edges) + list(static) for f in e}
    parent, child = _split_chain(chain, frames, path)
    # the chain's shape from the same search as static lookups; dynamic edges enter as placeholders
    shape = FrameTree([TransformRecord(0, a, b, np.eye(4)) for a, b in list(edges) + list(static)])
    hops = shape.path(parent, child)
    if hops is None:
        raise InputError(f"{path}: no chain of transforms connects '{parent}' to '{child}' in /tf and /tf_static")
    steps = [((a, b), False) if (a, b) in edges or (a, b) in static else ((b, a), True) for a, b in hops]
    series = {}
    for key, _ in steps:
        if key in edges:
            recs = sorted(edges[key], key=lambda r: r[0])
            st = np.array([r[0] for r in recs], dtype=np.int64)
            keep = np.concatenate([[True], np.diff(st) > 0])  # drop duplicated stamps
            series[key] = (st[keep], np.array([r[1] for r in recs])[keep])
    if not series:
        raise InputError(f"{path}: '{parent}' -> '{child}' is static (only /tf_static): no trajectory over time")
    main = max(series, key=lambda k: len(series[k][0]))
    stamps = series[main][0]
    lo = max(s[0][0] for s in series.values())
    hi = min(s[0][-1] for s in series.values())
    stamps = stamps[(stamps >= lo) & (stamps <= hi)]
    if len(stamps) == 0:
        raise InputError(f"{path}: the dynamic transforms on '{parent}' -> '{child}' never overlap in time")
    out = np.repeat(np.eye(4)[None], len(stamps), axis=0)
    for key, inverted in steps:
        if key in series:
            st, P = series[key]
            T = P[np.searchsorted(st, stamps)] if key == main else interpolate_poses(st, P, stamps)
        else:
            T = np.repeat(static[key][None], len(stamps), axis=0)
        out = out @ (inv_pose(T) if inverted else T)
    return Trajectory(stamps, out, f"{path}:tf:{parent}.{child}", "tf")


def _split_chain(chain: str, frames: set[str], path: Path) -> tuple[str, str]:
    if "->" in chain:
        a, _, b = chain.partition("->")
        candidates = [(a, b)]
    else:
        dots = [i for i, c in enumerate(chain) if c == "."]
        candidates = [(chain[:i], chain[i + 1:]) for i in dots]
    if not candidates:
        raise InputError(f"tf:{chain}: expected tf:PARENT.CHILD (or tf:PARENT->CHILD)")
    for a, b in candidates:
        a, b = a.strip("/"), b.strip("/")
        if a in frames and b in frames:
            return a, b
    known = ", ".join(sorted(frames)) or "none"
    raise InputError(f"{path}: frames of tf:{chain} not found in /tf and /tf_static (frames there: {known})")
