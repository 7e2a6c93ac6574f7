"""A LiDAR gap bridged by the IMU state: propagated across in scan-long steps, each corrected by the wheel speed
where there are wheels, then the scan after it registered from the prediction (see ``gaps``)."""

from __future__ import annotations

import numpy as np

from ...model.records import PointCloud
from ..imu import propagate
from .gaps import bridge_gate_m
from .imu_step import imu_step
from .state import OdomState, ScanResult
from .tuning import BRIDGE_STEP_NS
from .updates import wheel_update


def bridge(o: OdomState, cloud: PointCloud, t_prev: int, t_ref: int) -> ScanResult | None:
    """Carry the IMU state across a time gap, then register the scan after it from the prediction."""
    track, stats, nav, planar = o.track, o.stats, o.nav, o.settings.planar
    step_ns = int(track.last_dt_s * 1e9) if track.last_dt_s > 0 else BRIDGE_STEP_NS
    t_last = max(t_prev, t_ref - step_ns)  # the scan's own interval is the IMU step's
    imu = o.imu_window(t_prev)
    noise = o.settings.imu_noise
    saved, t, wheel_updates = nav.state, t_prev, stats.wheel_updates
    while t < t_last:
        t_next = min(t + step_ns, t_last)
        nav.state = propagate(nav.state, imu, t_next, o.ext, noise=noise, planar=planar).state
        if o.cfg.use_wheel:
            wheel_update(nav.state, o.wheel, t, t_next, o.cfg.fusion, stats)
        t = t_next
    predicted = propagate(nav.state, imu, t_ref, o.ext, planar=planar).state.p
    if o.clock is not None:
        o.clock.reset()  # its window of rates has a hole
    gap_s = (t_ref - t_prev) * 1e-9
    event = o.event("time gap", f"{gap_s:.3g} s without a scan: bridged by the IMU state"
                                f"{' and wheel speed' if stats.wheel_updates > wheel_updates else ''}")
    recoveries = stats.recoveries
    res = imu_step(o, cloud, t_last, t_ref, bridge_gate_m=bridge_gate_m(gap_s))
    if res is None:  # the scan was skipped: the next one bridges the gap again from where it began
        nav.state = saved
        event["reason"] += "; the scan after it was skipped"
    elif not res.failed and stats.recoveries == recoveries:
        moved = float(np.linalg.norm(res.pose[:3, 3] - predicted))
        event["reason"] += f"; the scan after it registered {moved:.2f} m from the prediction"
    return res
