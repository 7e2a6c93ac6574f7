"""Are two sensors stamped on the same clock? Checked from the first messages, before any work.

Drivers start in any order, so first stamps may differ by seconds; but each message is also recorded at
(nearly) the moment it arrives, so a header stamp minus its record time is about the same for every sensor
on one clock. Two sensors whose offsets differ by more than a few scan periods are on different clocks
(say, an IMU on its uptime and a LiDAR on epoch time): using them together would be silently wrong.

Unless their first stamps agree: then the sensors are on one clock and what differs is how late each was
recorded (a LiDAR's large clouds queued 0.5 s behind its stamps, while the IMU's small messages were not).
A log recorded from drivers already running starts every topic at once, so there the stamps alone tell.
"""

from __future__ import annotations

import numpy as np

from ...errors import InputError
from .peek import peek
from ..logs.base import LogReader

CLOCK_TOLERANCE_NS = 500_000_000  # a few scan periods; recording latency is far smaller
_FIRST = 5


def _stamp_offsets(log: LogReader, topic: str) -> tuple[np.ndarray, np.ndarray]:
    """(header stamps, header minus record time) of the first messages of ``topic``."""
    heads, recs = [], []
    for m in peek(log, topic, _FIRST):
        if m.stamp_ns is None:
            break
        heads.append(m.stamp_ns)
        recs.append(int(m.record_ns))
    h = np.asarray(heads, dtype=np.int64)
    return h, h - np.asarray(recs, dtype=np.int64)


def _fmt_s(ns: float) -> str:
    return f"{ns * 1e-9:.3f}"


def check_same_clock(log: LogReader, reference: str, other: str, other_offset_ns: int = 0,
                     option: str = "--imu-time-offset", reference_offset_ns: int = 0,
                     reference_option: str | None = None) -> None:
    """Refuse (InputError) when ``other``'s stamps (shifted by ``other_offset_ns``) are on another clock than
    ``reference``'s (shifted by ``reference_offset_ns``); the message names both time ranges and ``option`` with
    the value for ``other`` that fixes it (``option`` ending in ``=`` takes the value without a space), and
    ``reference_option``'s for ``reference`` where given."""
    h_ref, d_ref = _stamp_offsets(log, reference)
    h_oth, d_oth = _stamp_offsets(log, other)
    if len(h_ref) == 0 or len(h_oth) == 0:
        return
    apart = float(np.median(d_oth)) + other_offset_ns - float(np.median(d_ref)) - reference_offset_ns
    first = int(h_oth[0]) + other_offset_ns - int(h_ref[0]) - reference_offset_ns
    if abs(apart) <= CLOCK_TOLERANCE_NS or abs(first) <= CLOCK_TOLERANCE_NS:
        return
    sep = "" if option.endswith("=") else " "
    total = (other_offset_ns - apart) * 1e-9  # the offset that puts them on one clock, the one given included
    if other_offset_ns and abs(total) * 1e9 <= CLOCK_TOLERANCE_NS:
        fix = f"they agree without the {other_offset_ns * 1e-9:.3f} s offset given: give {option}{sep}0 or leave it out"
    else:
        fix = f"if {other} runs on a shifted clock give {option}{sep}{total:.3f}"
        if reference_option:
            fix += f"; if {reference} does, give {reference_option}{(reference_offset_ns + apart) * 1e-9:.3f}"
    raise InputError(
        f"{log.path}: {other} and {reference} are stamped on different clocks ({other} from "
        f"{_fmt_s(h_oth[0] + other_offset_ns)} s, {reference} from {_fmt_s(h_ref[0] + reference_offset_ns)} s: {abs(apart) * 1e-9:.6g} s "
        f"apart beyond their recording times); {fix}"
    )


def check_overlap(log: LogReader, reference: str, other: str, what: str) -> None:
    """Refuse when ``other`` has no message inside ``reference``'s recorded time range."""
    a, b = log.topics[reference], log.topics[other]
    if None in (a.first_ns, a.last_ns, b.first_ns, b.last_ns):
        return
    if b.last_ns < a.first_ns or b.first_ns > a.last_ns:
        raise InputError(
            f"{log.path}: no {what} message ({other}) inside the time range of {reference} (recorded "
            f"{_fmt_s(b.first_ns)}-{_fmt_s(b.last_ns)} s against {_fmt_s(a.first_ns)}-{_fmt_s(a.last_ns)} s)"
        )
