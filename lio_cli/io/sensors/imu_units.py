"""An IMU whose accelerations are in g, not m/s^2 (Livox's built-in IMU and some others write them so).

sensor_msgs/Imu says m/s^2, but a driver that passes the sensor's g through gives gravity as 1.0: every
integration is then ten times too weak, with no error anywhere.
The first samples of the topic tell: the median magnitude of a specific force is near gravity, 9.8 in m/s^2,
near 1 in g, whatever the platform does (a body that is not falling averages out to gravity over a second).
A median between ``G_RANGE`` is taken as g and scaled by standard gravity; anything else is left as it is.
"""

from __future__ import annotations

import math
import weakref

from .peek import peek
from ..logs.base import LogReader

STANDARD_GRAVITY_MPS2 = 9.80665
G_RANGE = (0.5, 2.0)  # median |a| of an IMU writing g; one writing m/s^2 reads 5-15 even in brisk motion
_SAMPLES = 200  # about a second of a typical IMU

_found: "weakref.WeakKeyDictionary[LogReader, dict[str, tuple[float, str | None]]]" = weakref.WeakKeyDictionary()


def accel_scale(log: LogReader, topic: str) -> tuple[float, str | None]:
    """(factor that turns the topic's accelerations into m/s^2, a note saying why when it is not 1)."""
    known = _found.setdefault(log, {})
    if topic not in known:
        norms = sorted(n for m in peek(log, topic, _SAMPLES)
                       if len(m.values) == 6 and math.isfinite(n := math.hypot(*m.values[3:])))
        median = norms[len(norms) // 2] if norms else math.nan
        if G_RANGE[0] <= median <= G_RANGE[1]:
            known[topic] = (STANDARD_GRAVITY_MPS2, f"its accelerations are in g, not m/s^2 (median magnitude "
                            f"{median:.2f} over its first {len(norms)} samples, where gravity reads 9.8 in m/s^2): "
                            f"scaled by {STANDARD_GRAVITY_MPS2}")
        else:
            known[topic] = (1.0, None)
    return known[topic]
