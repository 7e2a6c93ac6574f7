"""Per-source bookkeeping of a fusion run: what was received, used, rejected (and why), and noticed."""

from __future__ import annotations

from dataclasses import dataclass, field

# Why a sample or measurement did not enter the estimate.
REJECT_REASONS = {
    "nan": "a value was NaN or infinite",
    "out_of_range": "a value beyond any sensor's range (IMU: 1e4 m/s^2, 1e3 rad/s; wheel: 1e3 m/s or rad/s)",
    "all_zero": "every IMU value was exactly zero (a placeholder message, not a measurement)",
    "duplicate_stamp": "another sample had the same stamp (the first one was kept)",
    "invalid_pose": "the pose's rotation was not a rotation (e.g. quaternion 0,0,0,0)",
    "no_fix": "the GPS fix status said invalid",
    "stale_fix": "a GPS fix repeating the one before it exactly (latitude, longitude, altitude) while the wheels or "
                 "odometry moved: a receiver repeating its last position, left out",
    "outside_span": "stamped outside the time span of the motion sources",
    "outlier": "innovation beyond the chi-square gate (gate_probability) against the prediction",
    "multipath_jump": "a GPS fix inside a jump of the track its own motion cannot explain (multipath), until the "
                      "track comes back",
    "in_gap": "stamped inside a gap of every motion source",
    "yaw_slip": "a wheel yaw rate far (beyond the gate) from the bias-corrected gyro's, where the wheels' yaw rate "
                "is otherwise used beside the gyro: a slip, left out",
    "orientation_unfollowed": "the IMU's own orientation did not follow its gyro (relative rotation over 2 s windows "
                              "against the integrated gyro): a frozen or broken attitude, left out",
    "yaw_unchecked": "a wheel yaw rate with no gyro mean to weigh it against (an IMU gap, outside the IMU's span), "
                     "where the wheels' yaw rate is otherwise used beside the gyro: left out",
}
# Things noticed and handled without dropping the value.
NOTE_REASONS = {
    "reordered": "arrived out of stamp order (sorted back into place)",
    "default_noise": "covariance missing, zero, negative or NaN: the configured default noise was used",
    "gaps": "pauses longer than the gap threshold (bridged in one step each)",
    "gate_reset": "accepted after too many rejections in a row (the filter was assumed off)",
    "anchor": "used to tie the source's frame to the fused world frame",
    "orientation_absent": "the message carried no valid orientation (quaternion 0 or covariance -1)",
    "jump_readmitted": "GPS fixes flagged as a jump but used: the filter's own uncertainty or a run of fixes "
                       "agreeing with it showed the filter, not the fix, was off",
    "jumps": "GPS jumps found (multipath; their fixes are rejected as multipath_jump)",
    "jump_kept": "GPS jumps that lasted so long they were taken as the receiver's new level",
    "dropouts": "GPS pauses of over 5 periods, bridged by the motion sources",
    "noise_raised": "GPS fixes whose claimed sigma the innovations showed optimistic: the measured one was used",
    "snapped": "applied at an IMU sample at most FuseOptions.snap_ns away instead of at its own stamp",
    "slip_bridged": "wheel speeds during a slip (they changed by more than the accelerometer felt): the IMU's "
                    "speed was used in their place",
    "slip_left_in": "wheel speeds of a slip longer than 5 s the IMU's speed did not close: used as they are, "
                    "kept out of the wheel scale fit",
    "scale_corrected": "wheel speeds multiplied by the wheel scale the accelerometer measured",
    "gyro_gap_yaw": "wheel yaw rates used for the turn rate inside gaps of the gyro (no gyro there to prefer)",
    "yaw_noise_estimated": "wheel yaw rates used beside the gyro with the noise their residual against the gyro "
                           "shows (the message's or the default replaced)",
}


@dataclass
class SourceReport:
    """Counters of one source. ``updates`` counts measurement updates applied: one per measurement kind
    of a message (a wheel message with velocity and yaw rate makes two), broken down in ``by_kind``
    (kind -> {"updates": n, "outlier": m}); IMU samples used as the motion model count as
    ``predictions``."""

    received: int = 0
    updates: int = 0
    predictions: int = 0
    rejected: dict[str, int] = field(default_factory=dict)
    notes: dict[str, int] = field(default_factory=dict)
    by_kind: dict[str, dict[str, int]] = field(default_factory=dict)

    def outcome(self, kind: str, status: str) -> None:
        """Count one update attempt of measurement ``kind``: ``ok``, ``reset`` (forced after a streak of
        rejections) or ``outlier``."""
        k = self.by_kind.get(kind) or self.by_kind.setdefault(kind, {"updates": 0, "outlier": 0})
        if status == "ok":  # the usual case first
            self.updates += 1
            k["updates"] += 1
            return
        if status == "outlier":
            self.reject("outlier")
            k["outlier"] += 1
            return
        self.updates += 1
        k["updates"] += 1
        if status == "reset":
            self.note("gate_reset")

    def reject(self, reason: str, n: int = 1) -> None:
        if n:
            self.rejected[reason] = self.rejected.get(reason, 0) + int(n)

    def note(self, reason: str, n: int = 1) -> None:
        if n:
            self.notes[reason] = self.notes.get(reason, 0) + int(n)

    @property
    def n_rejected(self) -> int:
        return sum(self.rejected.values())

    def to_dict(self) -> dict:
        return {"received": self.received, "updates": self.updates, "predictions": self.predictions,
                "rejected": dict(self.rejected), "notes": dict(self.notes),
                "by_kind": {k: dict(v) for k, v in self.by_kind.items()}}
