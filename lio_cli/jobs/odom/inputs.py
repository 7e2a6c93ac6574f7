"""What an odom run reads: topics by role (with reasons), clocks checked, extrinsics by frame id."""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from ...config.odom import OdomConfig
from ...errors import InputError
from ...io.sensors.clocks import check_overlap, check_same_clock
from ...io.messages.decode import IMU, LASERSCAN
from ...io.logs.base import LogReader
from ...io.sensors.tf import FrameTree, TfConflict
from ...io.sensors.topics import TopicChoice, choose_topic, unpublished
from ...model.calibration import Calibration
from ...so3 import so3_log

BASE_FRAME_NAMES = ("base_link", "base", "base_footprint")


@dataclass
class OdomInputs:
    """The topics an odom run reads, why each was taken, and whether the IMU is used."""

    roles: dict[str, TopicChoice]
    use_imu: bool
    planar: bool
    deskew: str

    @property
    def lidar(self) -> str:
        return self.roles["lidar"].topic

    @property
    def imu(self) -> str | None:
        return self.roles["imu"].topic if self.use_imu else None

    @property
    def wheel(self) -> str | None:
        choice = self.roles.get("wheel")
        return choice.topic if choice else None

    def describe(self) -> dict:
        return {role: {"topic": c.topic, "why": c.why} for role, c in self.roles.items()}


def choose_inputs(reader: LogReader, cfg: OdomConfig) -> OdomInputs:
    """Topics by role (one line, exit 2, when a needed one is missing, bogus or on another clock)."""
    inp = cfg.input
    roles = {"lidar": choose_topic(reader, "lidar", inp.lidar_topic)}
    lidar = roles["lidar"].topic
    deskew = cfg.resolved_deskew()
    needs_imu = cfg.prior == "imu" or deskew == "imu"
    has_imu_type = any(i.msgtype == IMU and i.count > 0 for i in reader.topics.values())
    roles["imu"] = choose_topic(reader, "imu", inp.imu_topic, required=needs_imu and has_imu_type)
    imu = roles["imu"].topic
    if imu is None and needs_imu:
        what = "--prior imu" if cfg.prior == "imu" else "--deskew imu"
        raise InputError(
            f"{reader.path}: no IMU topic (sensor_msgs/Imu){unpublished(reader, 'imu')} for {what}; run LiDAR-only with "
            "--prior constant-velocity --deskew constant-velocity, or name the topic with --imu-topic"
        )
    use_imu = imu is not None and needs_imu
    if use_imu:
        check_same_clock(reader, lidar, imu, cfg.calibration.imu_time_offset_ns)
        check_overlap(reader, lidar, imu, "IMU")
    if cfg.use_wheel or cfg.prior == "wheel":
        roles["wheel"] = choose_topic(reader, "wheel", inp.wheel_topic, required=cfg.prior == "wheel")
        if roles["wheel"].topic is not None:
            check_same_clock(reader, lidar, roles["wheel"].topic, 0, "--no-wheel (and a wheel log on the LiDAR's clock)")
    planar = cfg.planar if cfg.planar is not None else reader.topics[lidar].msgtype == LASERSCAN
    return OdomInputs(roles, use_imu, planar, deskew)


def root_base(tree: FrameTree, frame: str | None, notes: list[str]) -> str | None:
    """The base frame of a /tf_static that names none of BASE_FRAME_NAMES: the root of the tree holding ``frame``
    (a driver's own tree, as Ouster's os_sensor -> os_lidar, os_imu, whose IMU-LiDAR mounting is then used, where
    identity was assumed for both before), with a note in ``notes`` saying so; None when no tree holds it."""
    root = tree.root(frame) if frame else None
    if root is not None:
        notes.append(f"base frame '{root}': the root of /tf_static's tree holding '{frame.lstrip('/')}' "
                     f"(none is named {', '.join(BASE_FRAME_NAMES)}; --base-frame chooses another)")
    return root


def named_base(tree: FrameTree, base_frame: str | None) -> str | None:
    """--base-frame, else the first of BASE_FRAME_NAMES that /tf_static holds, else None (see ``root_base``)."""
    return base_frame or next((b for b in BASE_FRAME_NAMES if b in tree.frames), None)


SAME_MOUNTING_M, SAME_MOUNTING_RAD = 1e-6, 1e-6  # closer than this: the same mounting, nothing to say


def mounting_apart(T_a: np.ndarray, T_b: np.ndarray) -> tuple[float, float]:
    """How far apart two mountings are: (translation in m, rotation angle in rad)."""
    T_a, T_b = np.asarray(T_a, float), np.asarray(T_b, float)
    dt = float(np.linalg.norm(T_a[:3, 3] - T_b[:3, 3]))
    dr = float(np.linalg.norm(so3_log(T_a[:3, :3].T @ T_b[:3, :3])))
    return dt, dr


def prefer_between(name: str, chain: str, T_tf: np.ndarray, calibration: Calibration, notes: list[str]
                   ) -> tuple[np.ndarray, str]:
    """(mounting, where from) of ``name`` when the log (``T_tf``, by ``chain``: "/tf_static (base -> imu)") and
    the calibration both give it: the log's, or the calibration's with ``prefer_file``; a note in ``notes``
    says how far apart they are when they differ."""
    T_file = calibration.matrix(name)
    prefer = calibration.prefer_file
    dt, dr = mounting_apart(T_tf, T_file)
    if dt > SAME_MOUNTING_M or dr > SAME_MOUNTING_RAD:
        used = "--calib's (--prefer-calib)" if prefer else "the log's (--prefer-calib uses --calib's)"
        notes.append(f"{name}: {chain} and --calib are {100 * dt:.2f} cm and {np.degrees(dr):.3f} deg apart; "
                     f"using {used}")
    if prefer:
        return T_file, f"--calib (--prefer-calib; the log has {chain})"
    return T_tf, chain


@dataclass
class Mounting:
    """Extrinsics as they are resolved (the LiDAR's at the first scan, the IMU's at its first message)."""

    tree: FrameTree
    calibration: Calibration
    base: str | None  # None until the first lookup when /tf_static names no usual base frame (``_base_for``)
    notes: list[str]
    sources: dict[str, str] = field(default_factory=dict)

    @classmethod
    def of(cls, tree: FrameTree, calibration: Calibration, base_frame: str | None, notes: list[str]) -> "Mounting":
        base = named_base(tree, base_frame) or (None if tree.frames else "base")
        notes.extend(w for w in tree.warnings if w not in notes)
        return cls(tree, calibration, base, notes, {"T_base_imu": "not used (no IMU in this run)"})

    def _base_for(self, frame: str) -> str:
        """The base frame; when /tf_static names none of the usual ones, ``root_base`` of the first sensor frame
        looked up."""
        if self.base is None:
            self.base = root_base(self.tree, frame, self.notes) or "base"
        return self.base

    def resolve(self, name: str, frame: str) -> np.ndarray:
        """``name`` (T_base_imu or T_base_lidar) from /tf_static by frame_id, else the calibration, else identity
        (the calibration's before /tf_static's with ``prefer_file``; a note when both give it and they differ).

        A /tf_static that contradicts itself on the chain needed stops the run (exit 2) unless the calibration
        gives this extrinsic."""
        self._base_for(frame)
        try:
            T = self.tree.lookup(self.base, frame) if frame else None
        except TfConflict:
            if self.calibration.matrix(name) is None:
                raise
            self.sources[name] = "--calib (/tf_static contradicts itself on this chain)"
            return self.calibration.matrix(name)
        if T is not None:
            chain = f"{self.tree.source(self.base, frame)} ({self.base} -> {frame})"
            if self.calibration.matrix(name) is None:
                self.sources[name] = chain
                return T
            T, self.sources[name] = prefer_between(name, chain, T, self.calibration, self.notes)
            return T
        if self.calibration.matrix(name) is not None:
            self.sources[name] = "--calib"
            if name == "T_base_imu" and self.calibration.unmeasured_rotation():
                self.notes.append(self.calibration.unmeasured_rotation())
            return self.calibration.matrix(name)
        self.notes.append(f"no extrinsic {name} ({self.base} -> {frame or '?'}) in /tf_static or --calib: "
                          "identity assumed")
        self.sources[name] = "identity (assumed)"
        return np.eye(4)

    def describe(self) -> dict:
        return {"base_frame": self.base, **self.sources}
