"""Which topic of a log plays which role (lidar, imu, wheel, gt), and why.

A topic asked for is checked and taken. Otherwise the candidates are the topics of the role's message types
that carry messages, minus those that cannot play it:

- wheel odometry never comes from a topic whose name or frames say ground truth (ground_truth, gt, vicon,
  mocap, optitrack...) or another estimator's output (filtered, ekf, slam, visual or stereo odometry...), nor
  from one whose twist is all zero over its first messages (a pose source: it would drag the velocity to
  zero); of several left, one named for wheels is preferred (the odometry also ignores all-zero twists
  while the platform moves);
- an IMU whose rates and accelerations are all zero is not an IMU;
- ground truth prefers a topic named so; an Odometry topic is ground truth only when named so.

One candidate left is taken; several are refused with the flag that chooses (unless one is plainly named
for the role, such as ``wheel``). Every choice comes with its reason, for notes and metrics.
"""

from __future__ import annotations

import re
from dataclasses import dataclass

import numpy as np

from ...errors import InputError
from ..messages.decode import IMU, KIND_FLAGS, KIND_TYPES, ODOMETRY
from .imu_units import accel_scale
from .peek import peek
from ..logs.base import LogReader

_KIND_WORDS = {"lidar": "LiDAR", "imu": "IMU", "wheel": "wheel odometry", "gt": "ground-truth", "gps": "GPS (NavSatFix)"}
_GT_TOKENS = {"gt", "groundtruth", "truth", "vicon", "mocap", "optitrack", "qualisys", "motioncapture"}
_GT_PHRASES = ("ground_truth", "ground-truth", "groundtruth", "motion_capture")
_ESTIMATE_TOKENS = {"filtered", "ekf", "ukf", "fused", "fusion", "slam", "lio", "loam", "liom", "estimate",
                    "estimated", "localization", "localisation", "amcl", "vo", "vio", "visual", "stereo", "camera",
                    "icp", "kiss", "lidar", "laser", "scan", "orb", "vins", "rtabmap", "cartographer"}
_WHEEL_TOKENS = {"wheel", "wheels", "encoder", "encoders", "controller", "diff", "drive", "odom_wheel", "base"}
_PEEK = 20  # messages looked at per candidate
_PEEK_TWIST = 1000  # a wheel topic's first messages may all be at rest: look further before calling it all zero


@dataclass(frozen=True)
class TopicChoice:
    """The topic taken for a role (None: none) and the reason, in words."""

    topic: str | None
    why: str


def _tokens(text: str) -> set[str]:
    return {t for t in re.split(r"[^a-z0-9]+", text.lower()) if t}


def says_ground_truth(*names: str) -> bool:
    """A topic or frame name that marks ground truth (ground_truth, gt, vicon, mocap, optitrack...)."""
    text = " ".join(names).lower()
    return any(p in text for p in _GT_PHRASES) or bool(_tokens(text) & _GT_TOKENS)


def says_estimate(name: str) -> bool:
    """A topic name that marks another estimator's output (odometry/filtered, ekf, slam, visual odometry...)."""
    return bool(_tokens(name) & _ESTIMATE_TOKENS)


def imu_is_all_zero(log: LogReader, topic: str) -> bool:
    """The first messages of an IMU topic hold nothing but zeros (rates and accelerations)."""
    seen = False
    for m in peek(log, topic, _PEEK):
        seen = True
        if any(v != 0.0 for v in m.values):
            return False
    return seen


def _wheel_verdict(log: LogReader, topic: str) -> str | None:
    """Why ``topic`` cannot be wheel odometry, or None when it can."""
    if says_ground_truth(topic):
        return "named as ground truth"
    if says_estimate(topic):
        return "named as another estimator's output"
    n = 0
    for m in peek(log, topic, _PEEK_TWIST):
        if n == 0 and says_ground_truth(m.frame_id, m.child_frame_id):
            return "its frames are named as ground truth"
        n += 1
        if np.abs(np.array(m.values, float)).sum() > 0:
            return None
    if n:
        return f"its twist is all zero over its first {n} messages (a pose source)"
    return None


def unpublished(log: LogReader, kind: str) -> str:
    """' (TOPIC is declared but never published)' for a log whose only ``kind`` topics hold no message (an empty
    recording), else ''."""
    accepted = KIND_TYPES[kind]
    if any(i.msgtype in accepted and i.count > 0 for i in log.topics.values()):
        return ""
    silent = sorted(t for t, i in log.topics.items() if i.msgtype in accepted)
    if not silent:
        return ""
    return f" ({', '.join(silent)} {'is' if len(silent) == 1 else 'are'} declared but never published)"


def choose_topic(log: LogReader, kind: str, requested: str | None = None, required: bool = True,
                 exclude: tuple[str, ...] = ()) -> TopicChoice:
    """The topic for ``kind`` (lidar, imu, wheel, gt) and why; see the module's rules."""
    accepted = KIND_TYPES[kind]
    word = _KIND_WORDS[kind]
    if requested is not None:
        _check_requested(log, kind, requested)
        return _with_units(log, kind, TopicChoice(requested, f"asked for with {KIND_FLAGS[kind]}"))
    # a topic declared but never published is as good as absent
    candidates = sorted(t for t, i in log.topics.items()
                        if i.msgtype in accepted and t not in exclude and i.count > 0)
    refused: dict[str, str] = {}
    if kind == "wheel":
        for t in candidates:
            verdict = _wheel_verdict(log, t)
            if verdict is not None:
                refused[t] = verdict
    elif kind == "imu":
        refused = {t: "its rates and accelerations are all zero" for t in candidates if imu_is_all_zero(log, t)}
    elif kind == "gt":
        named = [t for t in candidates if says_ground_truth(t)]
        poses = [t for t in candidates if log.topics[t].msgtype != ODOMETRY]
        keep = named or poses  # Odometry is ground truth only when named so
        refused = {t: "an Odometry topic not named as ground truth" for t in candidates if t not in keep}
    left = [t for t in candidates if t not in refused]
    left_out = "; ".join(f"{t}: {why}" for t, why in refused.items())
    if not left:
        if kind == "imu" and refused and required:
            raise InputError(f"{log.path}: IMU topic {', '.join(refused)} carries only zeros (rates and accelerations): "
                             "not an IMU; run LiDAR-only with --prior constant-velocity --deskew constant-velocity")
        silent = unpublished(log, kind) if kind in ("lidar", "imu") and not candidates else ""
        if required and silent:  # declared, never published: not "no topic of the type"
            empty = "" if any(i.count for i in log.topics.values()) else "the log holds no message at all: "
            raise InputError(f"{log.path}: no {word} data{silent}; {empty}check the recording")
        if required:
            extra = f" ({left_out})" if left_out else ""
            raise InputError(f"{log.path}: no {word} topic (none of type {', '.join(accepted)}){extra}")
        return TopicChoice(None, f"none found{f' ({left_out})' if left_out else ''}")
    if len(left) > 1 and kind == "wheel":
        plain = [t for t in left if _tokens(t) & _WHEEL_TOKENS]
        if len(plain) == 1:
            others = [t for t in left if t != plain[0]]
            return TopicChoice(plain[0], f"named as wheel odometry (also present: {', '.join(others)})"
                               + (f"; left out {left_out}" if left_out else ""))
    if len(left) > 1:
        raise InputError(
            f"{log.path}: several {word} topics ({', '.join(left)}); choose one with {KIND_FLAGS[kind]}"
        )
    why = f"the only {word} topic" if not refused else f"the only {word} topic left (left out {left_out})"
    if kind == "gt" and says_ground_truth(left[0]):
        why = "named as ground truth" + (f" (left out {left_out})" if refused else "")
    return _with_units(log, kind, TopicChoice(left[0], why))


def _with_units(log: LogReader, kind: str, choice: TopicChoice) -> TopicChoice:
    """An IMU's choice says when its accelerations are read as g (every reader scales them alike)."""
    if kind != "imu":
        return choice
    _, note = accel_scale(log, choice.topic)
    return choice if note is None else TopicChoice(choice.topic, f"{choice.why}; {note}")


def _check_requested(log: LogReader, kind: str, requested: str) -> None:
    accepted = KIND_TYPES[kind]
    word = _KIND_WORDS[kind]
    info = log.topics.get(requested)
    candidates = sorted(t for t, i in log.topics.items() if i.msgtype in accepted)
    if info is None:
        hint = f"; {word} topics here: {', '.join(candidates)}" if candidates else f"; it has no {word} topic"
        raise InputError(f"{log.path}: topic {requested} not found{hint}")
    if info.msgtype not in accepted:
        hint = f"; {word} topics here: {', '.join(candidates)}" if candidates else f"; the log has no {word} topic"
        raise InputError(
            f"{log.path}: topic {requested} is {info.msgtype}, not a {word} type ({', '.join(accepted)}){hint}"
        )
    if info.count == 0:
        raise InputError(f"{log.path}: topic {requested} has no messages")
    if info.msgtype == IMU and imu_is_all_zero(log, requested):
        raise InputError(f"{log.path}: IMU topic {requested} carries only zeros (rates and accelerations): not an IMU")


def select_topic(log: LogReader, kind: str, requested: str | None = None, required: bool = True,
                 exclude: tuple[str, ...] = ()) -> str | None:
    """The topic to read for ``kind``: ``choose_topic`` without the reason."""
    return choose_topic(log, kind, requested, required, exclude).topic
