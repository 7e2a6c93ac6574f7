"""What a fuse run reads: each source's topic (or file) and why, clocks checked, the IMU's extrinsic by its
frame id, and the core's input series with the measurement selection resolved.

Refused with one line (exit 2) before any estimation: no motion source; an IMU in a frame that neither
/tf_static nor ``--calib`` places on the base; GPS without a valid fix; sources on different clocks.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from ...config.fuse import FuseConfig
from ...core.fuse import FuseInputs, FuseOptions
from ...core.fuse.inputs import resolve_use
from ...errors import InputError
from ...io.sensors.gps import read_gps_track
from ...io.logs.base import LogReader
from ...io.sensors.series import POSE_TYPES, Progress, read_series
from ...io.sensors.sources import load_trajectory
from ...io.sensors.tf import FrameTree, TfConflict, read_static_frames
from ...io.sensors.topics import TopicChoice, choose_topic
from ...geodesy import EnuFrame
from ...model.gps import GpsTrack
from ..odom.inputs import prefer_between
from .clocks import check_clocks, offset_ns, shifted
from .orientation import leave_out_orientation
from .convert import (
    calibrated_wheel, carries_lateral_speed, gps_series, imu_series, pose_series, trajectory_series, twist_frame,
    wheel_series,
)
from ..odom.inputs import BASE_FRAME_NAMES, named_base, root_base

MOTION = ("imu", "wheel", "odom")


@dataclass
class FuseSources:
    """The sources of one run, read and converted, with everything the resolved config and metrics need."""

    inputs: FuseInputs
    use: dict[str, list[str]]
    roles: dict[str, dict]  # source -> {"topic" or "file", "why"}
    base_frame: str
    wheel_twist_frame: str | None
    gps: GpsTrack | None
    extrinsics: dict[str, str] = field(default_factory=dict)
    notes: list[str] = field(default_factory=list)
    checks: dict = field(default_factory=dict)  # "imu_orientation": the gyro check's figures where it left it out


def _wanted(cfg: FuseConfig) -> set[str]:
    """Sources to look for: the selection's, or every one (odometry poses only when named)."""
    if cfg.use is not None:
        return {s for s, m in cfg.use.items() if m}
    out = {"imu", "wheel", "gps"}
    if cfg.input.odom_topic or cfg.input.odom_file:
        out.add("odom")
    return out


def choose_sources(reader: LogReader, cfg: FuseConfig) -> dict[str, TopicChoice]:
    """Topic (or file) per source, and why; missing sources the selection asks for are errors."""
    inp, wanted = cfg.input, _wanted(cfg)
    explicit = cfg.use is not None
    roles: dict[str, TopicChoice] = {}
    for src, kind, requested in (("imu", "imu", inp.imu_topic), ("wheel", "wheel", inp.wheel_topic),
                                 ("gps", "gps", inp.gps_topic)):
        if src in wanted:
            choice = choose_topic(reader, kind, requested, required=explicit)
            if choice.topic is not None:
                roles[src] = choice
    if "odom" in wanted:
        if inp.odom_file:
            roles["odom"] = TopicChoice(None, f"file {inp.odom_file} (--odom)")
        elif inp.odom_topic:
            _check_pose_topic(reader, inp.odom_topic)
            roles["odom"] = TopicChoice(inp.odom_topic, "asked for with --odom-topic")
        else:
            raise InputError("the selection uses odom but names no odometry: give --odom FILE or --odom-topic TOPIC")
    if not set(roles) & set(MOTION):
        raise InputError(f"{reader.path}: no motion source: no IMU or wheel odometry topic found and no odometry "
                         "given (GPS alone cannot be fused); give --odom FILE, --odom-topic, --imu-topic or --wheel-topic")
    return roles


def _check_pose_topic(reader: LogReader, topic: str) -> None:
    info = reader.topics.get(topic)
    if info is None:
        raise InputError(f"{reader.path}: topic {topic} not found")
    if info.msgtype not in POSE_TYPES:
        raise InputError(f"{reader.path}: topic {topic} is {info.msgtype}, not a pose source "
                         f"({', '.join(POSE_TYPES)})")
    if info.count == 0:
        raise InputError(f"{reader.path}: topic {topic} has no messages")


def base_frame_of(cfg: FuseConfig, tree: FrameTree, wheel_child: str | None, imu_frame: str | None,
                  notes: list[str] | None = None) -> str:
    """--base-frame; else a usual base name in /tf_static; else the wheel twist's child frame; else the IMU's
    frame when it has a base's name; else the root of /tf_static's tree holding the IMU's (or the wheels') frame
    (a driver's own tree, as odom and deskew take it; a note says so); else ``base``."""
    named = named_base(tree, cfg.input.base_frame)
    if named:
        return named
    for f in (wheel_child, imu_frame):
        f = (f or "").lstrip("/")
        if f in BASE_FRAME_NAMES:
            return f
    for f in (imu_frame, wheel_child):
        root = root_base(tree, f, [] if notes is None else notes)
        if root is not None:
            return root
    return "base"


def imu_extrinsic(tree: FrameTree, cfg: FuseConfig, base: str, frame: str, topic: str, log: Path,
                  notes: list[str] | None = None) -> tuple[np.ndarray, str]:
    """T_base_imu by the IMU's frame id: the base itself, /tf_static (or --calib's with prefer_file, a note in
    ``notes`` when both give it and they differ), or --calib; else bad input."""
    f = frame.lstrip("/")
    if f == base:
        return np.eye(4), f"identity: the IMU's frame '{f}' is the base frame"
    try:
        T = tree.lookup(base, f) if f else None
    except TfConflict:  # /tf_static contradicts itself on this chain: only --calib settles it
        if cfg.calibration.T_base_imu is None:
            raise
        return cfg.calibration.matrix("T_base_imu"), "--calib (/tf_static contradicts itself on this chain)"
    if T is not None:
        chain = f"{tree.source(base, f)} ({base} -> {f})"
        if cfg.calibration.T_base_imu is None:
            return T, chain
        return prefer_between("T_base_imu", chain, T, cfg.calibration, [] if notes is None else notes)
    if cfg.calibration.T_base_imu is not None:
        return cfg.calibration.matrix("T_base_imu"), "--calib"
    raise InputError(f"{log}: IMU {topic} is in frame '{f or '(none)'}' and neither /tf_static nor --calib gives "
                     f"T_base_imu ({base} -> {f or '?'}); pass --calib with T_base_imu (lio calibrate writes one)")


def gather_sources(reader: LogReader, cfg: FuseConfig, progress: Progress | None = None) -> FuseSources:
    """Choose, check, read and convert every source of the run (see the module docstring)."""
    roles = choose_sources(reader, cfg)
    cal = cfg.calibration
    check_clocks(reader, roles, cal.imu_time_offset_ns, cfg.time_offsets_s)
    notes: list[str] = []
    topics = [roles[s].topic for s in ("imu", "wheel", "odom") if s in roles and roles[s].topic is not None]
    cols = read_series(reader, topics, progress)
    tree = read_static_frames(reader)
    notes.extend(tree.warnings)
    imu_cols = cols.get(roles["imu"].topic) if "imu" in roles else None
    wheel_cols = cols.get(roles["wheel"].topic) if "wheel" in roles else None
    base = base_frame_of(cfg, tree, wheel_cols.child_frame_id if wheel_cols is not None else None,
                         imu_cols.frame_id if imu_cols is not None else None, notes)
    inputs, extrinsics, twist = FuseInputs(), {}, None
    if imu_cols is not None and len(imu_cols):
        T, why = imu_extrinsic(tree, cfg, base, imu_cols.frame_id, imu_cols.topic, reader.path, notes)
        extrinsics["T_base_imu"] = why
        if why.startswith("--calib") and cal.unmeasured_rotation():
            notes.append(cal.unmeasured_rotation())
        if len(imu_cols.frames) > 1:
            notes.append(f"IMU {imu_cols.topic} changes frame id ({', '.join(imu_cols.frames)}): "
                         f"the first one's extrinsic is used")
        inputs.imu = imu_series(imu_cols, T, cal.imu_time_offset_ns, cal.gyro_bias_radps, cal.accel_bias_mps2)
    if wheel_cols is not None and len(wheel_cols):
        twist, why = (twist_frame(wheel_cols) if cfg.input.wheel_twist_frame == "auto" else
                      (cfg.input.wheel_twist_frame, "as configured"))
        extrinsics["wheel_twist"] = f"{twist} frame: {why}"
        if twist == "parent":
            notes.append(f"wheel odometry {wheel_cols.topic}: twist in the parent frame, not the base (REP 105): {why}")
        R = _child_rotation(tree, base, wheel_cols.child_frame_id, extrinsics)
        inputs.wheel = shifted(wheel_series(wheel_cols, twist, R), offset_ns(cfg, "wheel"))
        applies, said = cal.wheel.verdict(wheel_cols.topic) if cal.wheel is not None else (False, "")
        if applies:
            inputs.wheel = calibrated_wheel(inputs.wheel, cal.wheel)
            extrinsics["wheel_twist"] += f"; {said}"
        elif said:
            notes.append(said)
    if "odom" in roles:
        inputs.odom = shifted(_odom(cfg, cols), offset_ns(cfg, "odom"))
    gps = None
    if "gps" in roles:
        origin = EnuFrame(*cfg.input.gps_origin) if cfg.input.gps_origin else None
        gps = read_gps_track(reader, roles["gps"].topic, origin)
        antenna, extrinsics["gps_antenna"] = gps_antenna(tree, base, gps, notes, cfg.input.gps_antenna)
        inputs.gps = shifted(gps_series(gps, antenna), offset_ns(cfg, "gps"))
    checks: dict = {}
    use = resolved_use(cfg, inputs, notes, checks)
    described = {s: {"topic": c.topic, "why": c.why} for s, c in roles.items()}
    if "odom" in roles and roles["odom"].topic is None:
        described["odom"] = {"file": cfg.input.odom_file, "why": roles["odom"].why}
    return FuseSources(inputs, use, described, base, twist, gps, extrinsics, notes, checks)


def gps_antenna(tree: FrameTree, base: str, gps: GpsTrack, notes: list[str],
                given: list[float] | None = None) -> tuple[np.ndarray | None, str]:
    """The antenna's position on the base (base axes) and where it came from: ``given`` (the config's
    ``input.gps_antenna``), else /tf_static by the fixes' frame id; None (the base origin, with a note) where
    neither places it."""
    f = gps.frame_id
    try:
        T = tree.lookup(base, f) if f and f != base else None
    except TfConflict:
        T, why = None, f"/tf_static contradicts itself on {base} -> {f}"
    else:
        why = f"/tf_static has no chain {base} -> {f}" if f else "the fixes carry no frame id"
    if given is not None:
        a = np.asarray(given, float)
        if T is not None and np.linalg.norm(T[:3, 3] - a) > 0.01:
            notes.append(f"GPS {gps.topic}: input.gps_antenna used, {np.linalg.norm(T[:3, 3] - a):.3f} m from "
                         f"/tf_static's {base} -> {f}")
        return a, f"input.gps_antenna: {a[0]:.3f}, {a[1]:.3f}, {a[2]:.3f} m"
    if f == base:
        return None, f"at the base origin: the fixes' frame '{f}' is the base's"
    if T is None:
        notes.append(f"GPS {gps.topic}: the antenna taken at the base origin ({why}); a roof antenna's offset "
                     "then turns with the heading: give input.gps_antenna (x, y, z in the base frame) in --config")
        return None, f"at the base origin ({why})"
    a = T[:3, 3]
    return a.copy(), f"{tree.source(base, f)} ({base} -> {f}): {a[0]:.3f}, {a[1]:.3f}, {a[2]:.3f} m"


def _child_rotation(tree: FrameTree, base: str, child: str, extrinsics: dict) -> np.ndarray | None:
    child = child.lstrip("/")
    if not child or child == base:
        return None
    T = tree.lookup(base, child)
    if T is None or np.allclose(T[:3, :3], np.eye(3)):
        return None
    extrinsics["wheel_twist"] += f"; rotated from '{child}' into '{base}' (/tf_static)"
    return T[:3, :3]


def _odom(cfg: FuseConfig, cols: dict):
    if cfg.input.odom_topic:
        return pose_series(cols[cfg.input.odom_topic])
    traj = load_trajectory(cfg.input.odom_file)
    return trajectory_series(traj.stamps_ns, traj.poses)


def resolved_use(cfg: FuseConfig, inputs: FuseInputs, notes: list[str] | None = None,
                 checks: dict | None = None) -> dict[str, list[str]]:
    """The selection as given (a bare imu's orientation checked: ``check_orientation``), or the core's default for
    the sources present, with two io-informed changes (each noted): a wheel twist with a real lateral speed
    (holonomic base, drone) enters as ``velocity``, not as a forward ``speed`` with a non-holonomic constraint; an
    IMU orientation whose yaw variance says the heading is unknown, or that does not follow the gyro, is left out
    (``orientation``; the gyro check's figures into ``checks``)."""
    notes = notes if notes is not None else []
    if cfg.use is not None:
        use = {s: set(m) for s, m in cfg.use.items() if m}
        if cfg.check_orientation:  # a bare --use imu: its orientation checked as the default selection's
            _checked_orientation(inputs, use, notes, checks)
        return {s: sorted(m) for s, m in use.items()}
    use = resolve_use(inputs, FuseOptions())
    if "wheel" in use and carries_lateral_speed(inputs.wheel):
        use["wheel"] = (use["wheel"] - {"speed"}) | {"velocity"}
        notes.append("wheel twist with a lateral speed (holonomic base or drone): its velocity enters as measured, "
                     "without a non-holonomic constraint")
    if cfg.check_orientation is not False:
        _checked_orientation(inputs, use, notes, checks)
    return {s: sorted(m) for s, m in use.items()}


def _checked_orientation(inputs: FuseInputs, use: dict[str, set[str]], notes: list[str], checks: dict | None) -> None:
    if "orientation" in use.get("imu", ()) and inputs.imu is not None:
        checked = leave_out_orientation(inputs.imu, use, notes)
        if checked is not None and checks is not None:
            checks["imu_orientation"] = checked


__all__ = ["FuseSources", "base_frame_of", "check_clocks", "choose_sources", "gather_sources", "gps_antenna",
           "imu_extrinsic", "resolved_use"]
