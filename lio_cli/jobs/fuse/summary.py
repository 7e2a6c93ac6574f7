"""One line per source of a fuse run: what entered the estimate and what did not, and why, by measurement.

``imu: 12001 samples propagated, 301 orientation updates``; ``wheel: 3001 speed updates, 12 rejected (12 speed
innovation beyond the gate)``; ``gps: 412 used (vertical 405), 42 rejected (7 horizontal innovation beyond the
gate, 25 multipath jump, 10 no fix)``. The IMU driving the prediction is counted as samples propagated, so an
IMU without updates never reads as unused.
"""

from __future__ import annotations

KIND_LABEL = {"gyro": "gyro", "orientation": "orientation", "wheel_speed": "speed", "wheel_velocity": "velocity",
              "wheel_yaw_rate": "yaw rate", "odom": "pose", "gps": "horizontal", "gps_vertical": "vertical"}
REJECT_LABEL = {"no_fix": "no fix", "nan": "NaN", "out_of_range": "out of range", "all_zero": "all zero",
                "duplicate_stamp": "duplicate stamp", "invalid_pose": "invalid pose", "multipath_jump": "multipath jump",
                "stale_fix": "stale (repeating the fix before)",
                "outside_span": "outside the motion sources' span", "in_gap": "in a gap of every motion source",
                "yaw_slip": "yaw rate far from the gyro's (slip)", "yaw_unchecked": "yaw rate without the gyro",
                "orientation_unfollowed": "orientations not following the gyro"}
NOTE_LABEL = {"slip_bridged": "slip bridged by the IMU"}  # notes of values changed before use: after the used


def _label(kind: str) -> str:
    return KIND_LABEL.get(kind, kind.replace("_", " "))


def source_summary(src: str, updates: int, predictions: int, by_kind: dict[str, dict[str, int]],
                   rejected: dict[str, int], notes: dict[str, int] | None = None) -> str:
    """The source's line (module docstring) from its report's counters; ``notes`` adds the values changed
    before use (``NOTE_LABEL``: ``wheel: 1501 speed updates, 337 slip bridged by the IMU``)."""
    used = []
    if predictions:
        used.append(f"{predictions} samples propagated")
    kinds = dict(by_kind)
    if src == "gps" and "gps" in kinds:
        h = kinds.pop("gps")["updates"]
        v = kinds.pop("gps_vertical", {}).get("updates")
        used.append(f"{h} used" + (f" (vertical {v})" if v is not None else ""))
    used += [f"{c['updates']} {_label(k)} updates" for k, c in kinds.items()]
    if updates and not by_kind:  # the complementary filter's blends
        used.append(f"{updates} {'blends' if src != 'imu' else 'orientation blends'}")
    used += [f"{n} {label}" for k, label in NOTE_LABEL.items() if (n := (notes or {}).get(k))]
    why = [f"{c['outlier']} {_label(k)} innovation beyond the gate" for k, c in by_kind.items() if c.get("outlier")]
    why += [f"{n} {REJECT_LABEL.get(r, r.replace('_', ' '))}" for r, n in rejected.items() if r != "outlier" and n]
    total = sum(n for n in rejected.values())
    line = f"{src}: " + (", ".join(used) or "nothing used")
    return line + (f", {total} rejected ({', '.join(why)})" if total else "")
