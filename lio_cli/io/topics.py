"""Which topic of a log plays which role (lidar, imu, wheel, gt): the one asked for, or the only candidate."""

from __future__ import annotations

from ..errors import InputError
from .decode import KIND_FLAGS, KIND_TYPES
from .reader import LogReader

_KIND_WORDS = {"lidar": "LiDAR", "imu": "IMU", "wheel": "wheel odometry", "gt": "ground-truth"}


def select_topic(log: LogReader, kind: str, requested: str | None = None, required: bool = True,
                 exclude: tuple[str, ...] = ()) -> str | None:
    """The topic to read for ``kind`` (lidar, imu, wheel, gt): the one asked for, or the only candidate."""
    accepted = KIND_TYPES[kind]
    word = _KIND_WORDS[kind]
    if requested is not None:
        info = log.topics.get(requested)
        if info is None:
            candidates = sorted(t for t, i in log.topics.items() if i.msgtype in accepted)
            hint = f"; {word} topics here: {', '.join(candidates)}" if candidates else f"; it has no {word} topic"
            raise InputError(f"{log.path}: topic {requested} not found{hint}")
        if info.msgtype not in accepted:
            candidates = sorted(t for t, i in log.topics.items() if i.msgtype in accepted)
            hint = (f"; {word} topics here: {', '.join(candidates)}" if candidates
                    else f"; the log has no {word} topic")
            raise InputError(
                f"{log.path}: topic {requested} is {info.msgtype}, not a {word} type ({', '.join(accepted)}){hint}"
            )
        if info.count == 0:
            raise InputError(f"{log.path}: topic {requested} has no messages")
        return requested
    # a topic declared but never published is as good as absent
    candidates = sorted(t for t, i in log.topics.items()
                        if i.msgtype in accepted and t not in exclude and i.count > 0)
    if kind == "gt":  # Odometry is ambiguous between wheel and ground truth: only take it when named so
        poses = [t for t in candidates if log.topics[t].msgtype != "nav_msgs/msg/Odometry"]
        named = [t for t in candidates if any(w in t.lower() for w in ("ground_truth", "groundtruth", "gt"))]
        candidates = poses or named
    if not candidates:
        if required:
            raise InputError(f"{log.path}: no {word} topic (none of type {', '.join(accepted)})")
        return None
    if len(candidates) > 1:
        raise InputError(
            f"{log.path}: several {word} topics ({', '.join(candidates)}); choose one with {KIND_FLAGS[kind]}"
        )
    return candidates[0]
