"""The static scenario's log: hours of IMU samples at rest, made and written piece by piece.

Memory stays flat whatever the duration (one piece of ``PIECE_SAMPLES`` samples at a time; the bias random
walks carry over between pieces), and messages are serialised in bulk: one template message serialised by
the log writer, stamps and readings patched in with numpy (an Imu message of one frame_id has a fixed
layout in ROS 1 and in CDR). MCAP and ROS 2 outputs stream to disk; rosbags' ROS 1 writer keeps its message
index in memory (about 130 bytes per message).
"""

from __future__ import annotations

from collections.abc import Callable, Iterator
from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np

from ..errors import ProcessingError
from ..io.logs.writer import LogWriter
from .motion import MotionState, Trajectory
from .options import SimulationOptions
from .record import GT_MSGTYPES, TOPIC_IMU, TOPIC_TF_STATIC, gt_message, gt_type_of, static_transforms
from .scenarios import Scenario
from .sensors import NS, ImuData, ImuSpec, synthesize_imu

PIECE_SAMPLES = 12_000
STATIC_GT_RATE_HZ = 1.0
IMU_MSGTYPE = "sensor_msgs/msg/Imu"


class ImuEncoder:
    """Bulk serialiser of sensor_msgs/Imu messages with one ``frame_id`` for ``writer``'s format; its output
    is byte for byte what ``writer.serialize(writer.make.imu(...))`` gives."""

    _SEC, _NSEC = 1_234_567_891, 987_654_321
    _GYRO, _ACCEL = (101.0625, 202.125, 303.1875), (404.25, 505.3125, 606.375)

    def __init__(self, writer: LogWriter, frame_id: str) -> None:
        msg = writer.make.imu(self._SEC * NS + self._NSEC, frame_id, self._GYRO, self._ACCEL)
        raw = writer.serialize(msg, IMU_MSGTYPE)
        self.template = np.frombuffer(raw, dtype=np.uint8)

        def where(pattern: bytes) -> int:
            at = raw.find(pattern)
            if at < 0 or raw.find(pattern, at + 1) >= 0:
                raise ProcessingError("cannot bulk-serialise Imu messages: a patch value is not unique in the template")
            return at

        self.sec_at = where(np.array(self._SEC, "<u4").tobytes())
        self.nsec_at = where(np.array(self._NSEC, "<u4").tobytes())
        self.gyro_at = [where(np.array(v, "<f8").tobytes()) for v in self._GYRO]
        self.accel_at = [where(np.array(v, "<f8").tobytes()) for v in self._ACCEL]

    def encode(self, stamps_ns: np.ndarray, gyro_radps: np.ndarray, accel_mps2: np.ndarray) -> np.ndarray:
        """(N, message bytes) uint8: row i is the serialised message of sample i."""
        n = len(stamps_ns)
        buf = np.empty((n, len(self.template)), np.uint8)
        buf[:] = self.template
        stamps = np.asarray(stamps_ns, np.int64)
        buf[:, self.sec_at:self.sec_at + 4] = (stamps // NS).astype("<u4").view(np.uint8).reshape(n, 4)
        buf[:, self.nsec_at:self.nsec_at + 4] = (stamps % NS).astype("<u4").view(np.uint8).reshape(n, 4)
        for cols, at in ((gyro_radps, self.gyro_at), (accel_mps2, self.accel_at)):
            for j in range(3):
                buf[:, at[j]:at[j] + 8] = np.ascontiguousarray(cols[:, j], "<f8").view(np.uint8).reshape(n, 8)
        return buf


def imu_pieces(traj: Trajectory, T_base_imu: np.ndarray, spec: ImuSpec, start_ns: int, end_ns: int,
               traj_start_ns: int, rng: np.random.Generator | None, piece: int = PIECE_SAMPLES) -> Iterator[ImuData]:
    """:func:`synthesize_imu` over ``start_ns..end_ns`` in pieces of ``piece`` samples, the biases walking on
    across piece boundaries."""
    period_ns = int(round(NS / spec.rate_hz))
    n_total = (end_ns - start_ns) // period_ns + 1
    ba, bg = spec.accel_bias0_mps2, spec.gyro_bias0_radps
    for k0 in range(0, n_total, piece):
        k1 = min(n_total, k0 + piece)
        part = replace(spec, accel_bias0_mps2=ba, gyro_bias0_radps=bg)
        data = synthesize_imu(traj, T_base_imu, part, start_ns + k0 * period_ns, start_ns + (k1 - 1) * period_ns,
                              traj_start_ns, rng, continue_walk=k0 > 0)
        ba, bg = data.accel_bias_mps2[-1], data.gyro_bias_radps[-1]
        yield data


@dataclass
class BiasSummary:
    """First, last and mean true bias of a run written in pieces (for truth.json)."""

    first: dict | None = None
    last: dict | None = None
    sums: dict | None = None
    count: int = 0

    def add(self, data: ImuData) -> None:
        a, g = data.accel_bias_mps2, data.gyro_bias_radps
        if self.first is None:
            self.first, self.sums = {"accel": a[0], "gyro": g[0]}, {"accel": np.zeros(3), "gyro": np.zeros(3)}
        self.last = {"accel": a[-1], "gyro": g[-1]}
        self.sums = {"accel": self.sums["accel"] + a.sum(axis=0), "gyro": self.sums["gyro"] + g.sum(axis=0)}
        self.count += len(a)

    def as_dict(self) -> dict:
        """The ``bias_stats`` :func:`truth.truth_dict` takes."""
        return {"accel_first": self.first["accel"], "gyro_first": self.first["gyro"],
                "accel_last": self.last["accel"], "gyro_last": self.last["gyro"],
                "accel_mean": self.sums["accel"] / self.count, "gyro_mean": self.sums["gyro"] / self.count}


def write_static_log(out: Path, fmt: str, force: bool, sc: Scenario, opts: SimulationOptions, spec: ImuSpec,
                     start_ns: int, end_ns: int, gt_ns: np.ndarray, gt_state: MotionState,
                     rng: np.random.Generator | None,
                     progress: Callable[[float], None] | None) -> tuple[dict[str, str], dict[str, int], BiasSummary]:
    """Write the static scenario's log; returns (msgtype by topic, count by topic, bias summary)."""
    gt_type = gt_type_of(sc, opts)
    gt_poses = gt_state.poses
    summary = BiasSummary()
    counts: dict[str, int] = {}
    types: dict[str, str] = {}
    with LogWriter(out, fmt, force=force) as wr:
        mk = wr.make
        if opts.tf_static:
            types[TOPIC_TF_STATIC] = "tf2_msgs/msg/TFMessage"
            wr.add_topic(TOPIC_TF_STATIC, types[TOPIC_TF_STATIC], latching=True)
        types[TOPIC_IMU] = IMU_MSGTYPE
        wr.add_topic(TOPIC_IMU, IMU_MSGTYPE)
        if gt_type != "none":
            types[opts.gt_topic] = GT_MSGTYPES[gt_type]
            wr.add_topic(opts.gt_topic, types[opts.gt_topic])
        encoder = ImuEncoder(wr, "imu")
        first = True
        g = 0  # next ground-truth sample to write
        for data in imu_pieces(sc.trajectory, sc.T_base_imu, spec, start_ns, end_ns, start_ns, rng):
            summary.add(data)
            if first and opts.tf_static:
                first_ns = min(start_ns, int(data.stamps_ns[0]))
                wr.write(TOPIC_TF_STATIC, first_ns, static_transforms(mk, first_ns, sc, False))
                counts[TOPIC_TF_STATIC] = 1
            first = False
            rows = encoder.encode(data.stamps_ns, data.gyro_radps, data.accel_mps2)
            for i, t in enumerate(data.stamps_ns.tolist()):
                while gt_type != "none" and g < len(gt_ns) and gt_ns[g] < t:
                    wr.write(opts.gt_topic, int(gt_ns[g]), gt_message(mk, gt_type, opts.gt_twist, int(gt_ns[g]),
                                                                      gt_state, g, gt_poses[g]))
                    g += 1
                wr.write_raw(TOPIC_IMU, t, rows[i].tobytes())
            counts[TOPIC_IMU] = counts.get(TOPIC_IMU, 0) + len(rows)
            if progress is not None:
                progress(len(rows) / spec.rate_hz)
        while gt_type != "none" and g < len(gt_ns):
            wr.write(opts.gt_topic, int(gt_ns[g]), gt_message(mk, gt_type, opts.gt_twist, int(gt_ns[g]), gt_state, g,
                                                              gt_poses[g]))
            g += 1
        if gt_type != "none":
            counts[opts.gt_topic] = len(gt_ns)
    return types, counts, summary
