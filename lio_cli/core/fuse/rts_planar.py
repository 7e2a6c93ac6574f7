"""The planar filter's run (``planar``): its RTS pass, the path integrated again from the smoothed rates where
nothing measures the position, the next piece's start, the poses as the fusion's result."""

from __future__ import annotations

import copy
from dataclasses import replace

import numpy as np

from .inputs import FuseOptions
from .pieces import planar_handover
from .planar import PlanarEkf, se2
from .planar_model import TH, V, W, X, Y
from .result import FuseResult, anchor_to_origin, enu_origin
from .sanitize import median_period_ns
from .smoother import SingularPrediction, rts_smooth
from .start_state import Start
from .timeline import Prepared


def unmeasured_pose(prep: Prepared) -> bool:
    """Nothing measures the position (no GPS, no odometry), the motion sources have no gap, and the IMU verified the
    wheels (their speed scale, ``wheel_slip``, and yaw rate, ``wheel_yaw``) with no yaw scale to divide out: on
    wheels with a scale error or slips the half step is far below their own error."""
    yaw_scaled = bool((prep.wheel_yaw_check or {}).get("scale_applied"))
    return prep.wheels_verified and not yaw_scaled and not ({"gps", "odom"} & set(prep.use)) \
        and len(prep.coverage) == 1


def reintegrated(t_ns: np.ndarray, x: np.ndarray, heading: bool = True) -> np.ndarray:
    """Smoothed states with x, y (and, ``heading``, theta) integrated again from the smoothed speed and turn rate
    by the trapezoid rule. The model's step takes the speed and turn rate at the step's start, so its positions
    lag the speed by half a step (along the track wherever it turns); where no measurement holds the position,
    the smoothed rates integrated without that lag are the better path."""
    out = x.copy()
    dt = np.diff(t_ns) * 1e-9
    if heading:
        d_th = 0.5 * (x[1:, W] + x[:-1, W]) * dt
        th = x[0, TH] + np.concatenate([[0.0], np.cumsum(d_th)])
    else:
        th = np.unwrap(x[:, TH])
        d_th = np.diff(th)
    mid = th[:-1] + 0.5 * d_th
    ds = 0.5 * (x[1:, V] + x[:-1, V]) * dt
    out[:, X] = x[0, X] + np.concatenate([[0.0], np.cumsum(ds * np.cos(mid))])
    out[:, Y] = x[0, Y] + np.concatenate([[0.0], np.cumsum(ds * np.sin(mid))])
    out[:, TH] = (th + np.pi) % (2.0 * np.pi) - np.pi
    return out


def advanced(x: np.ndarray, lag_s: float) -> np.ndarray:
    """States with x, y and theta moved ``lag_s`` on by their own speed and turn rate. The model's step takes the
    rates at its start (a left sum), so its pose is the one half a gyro period before the knot's stamp: advanced by
    that half period, the pose is the stamp's."""
    out = x.copy()
    mid = x[:, TH] + 0.5 * x[:, W] * lag_s
    out[:, X] += x[:, V] * np.cos(mid) * lag_s
    out[:, Y] += x[:, V] * np.sin(mid) * lag_s
    out[:, TH] = (x[:, TH] + x[:, W] * lag_s + np.pi) % (2.0 * np.pi) - np.pi
    return out


def run_planar(prep: Prepared, o: FuseOptions, start: Start | None = None) -> FuseResult:
    """The planar filter, smoothed under ``o.smooth``. Where the RTS pass finds its predicted covariance singular
    (odometry increments: their clone is an exact copy of the pose when taken, and a knot can follow before time
    tells them apart), the run is the filter's alone, as ``--no-smooth`` gives it, with a note."""
    if not o.smooth:
        return _run(prep, o, start)
    counted = copy.deepcopy(prep.reports)
    try:
        return _run(prep, o, start)
    except SingularPrediction as err:
        prep.reports = counted  # the smoothing run's counts go with it
        result = _run(prep, replace(o, smooth=False), start)
        result.info["rts_refused"] = str(err)
        return result


def _run(prep: Prepared, o: FuseOptions, start: Start | None) -> FuseResult:
    ekf = PlanarEkf(prep, o, start)
    knots = ekf.run()
    x, P = knots["x_filt"], knots["P_filt"]
    lag_s = 0.5 * median_period_ns(prep.imu.stamps_ns) * 1e-9 if ekf.use_gyro else 0.0
    if o.smooth and len(x):
        x, P = rts_smooth(knots, ekf.boxplus, ekf.boxminus)
        if unmeasured_pose(prep):
            x = reintegrated(knots["t_ns"], x, heading="orientation" not in prep.use.get("imu", ()))
            lag_s = 0.0
    handover = None
    if o.handover_ns is not None and len(x):
        handover = planar_handover(knots["t_ns"], x, P, o.handover_ns) if o.smooth else \
            planar_handover(*ekf.handed, o.handover_ns)
    sel = knots["output"]
    if o.smooth:
        x, P = x[sel], P[sel][:, [X, Y, TH]][:, :, [X, Y, TH]] if o.want_covariance else None
    if lag_s > 0.0 and len(x):
        x = advanced(x, lag_s)
    poses = np.stack([se2(a[X], a[Y], a[TH]) for a in x]) if len(x) else np.zeros((0, 4, 4))
    cov = None
    if o.want_covariance:  # x, y, yaw into the 6x6 layout; z, roll, pitch are exactly known (planar)
        cov = np.zeros((len(x), 6, 6))
        cov[np.ix_(np.arange(len(x)), [0, 1, 5], [0, 1, 5])] = P
    vel = None
    if len(x):
        vel = np.column_stack([x[:, V] * np.cos(x[:, TH]), x[:, V] * np.sin(x[:, TH]), np.zeros(len(x))])
    info = {"model": "planar", "start": ekf.start.reason, "world_yaw_from": ekf.start.yaw_from,
            "odom_mode": next(iter(prep.use.get("odom", ())), None)}
    if handover is not None:
        info["handover"] = handover
    origin = enu_origin(poses, None if ekf.gps_offset is None else -ekf.gps_offset)
    return FuseResult(knots["t_ns"][sel], anchor_to_origin(poses), cov, vel, "planar", o.smooth, prep.reports, info,
                      origin)
