"""The smoothed trajectory at the output stamps: between keyframes k and k+1, the IMU predicts from keyframe k
(its smoothed state and bias); what the prediction misses at k+1 (the IMU factor's residual, millimetres) is
spread linearly over the interval, so the output meets every keyframe exactly and is as smooth as the IMU
between them; after the last keyframe, the IMU's prediction alone. An interval without IMU data (a gap) is
interpolated on the poses."""

from __future__ import annotations

import gtsam
import numpy as np

from .factors import nav
from .imu import Segments


def at_outputs(seg: Segments, kt: np.ndarray, s: dict[str, np.ndarray], params, out_ns: np.ndarray
               ) -> tuple[np.ndarray, np.ndarray]:
    """(N,4,4) poses and (N,3) velocities at ``out_ns`` (each at or after ``kt[0]``; after ``kt[-1]`` the IMU's
    prediction from it); ``seg`` is cut at both ``kt`` and ``out_ns``."""
    N = len(out_ns)
    poses, vel = np.zeros((N, 4, 4)), np.zeros((N, 3))
    k_of = np.clip(np.searchsorted(kt, out_ns, side="right") - 1, 0, len(kt) - 1)
    at_seg = np.searchsorted(seg.t, out_ns)
    for k in np.unique(k_of).tolist():
        sel = np.flatnonzero(k_of == k)
        T0 = nav(s["R"][k], s["p"][k])
        if k + 1 >= len(kt):
            _after(seg, kt, s, params, k, sel, out_ns, at_seg, poses, vel)
            continue
        _interval(seg, kt, s, params, k, T0, sel, out_ns, at_seg, poses, vel)
    return poses, vel


def _after(seg, kt, s, params, k, sel, out_ns, at_seg, poses, vel) -> None:
    """Outputs after the last keyframe: the IMU's prediction from it; past an IMU gap, the last output's before it."""
    bias = gtsam.imuBias.ConstantBias(s["ba"][k], s["bg"][k])
    ns = gtsam.NavState(gtsam.Rot3(s["R"][k]), s["p"][k], s["v"][k])
    start, pim = ns, gtsam.PreintegratedCombinedMeasurements(params, bias)
    cur, held = int(seg.at_cut_of(kt[k])), False
    for n in sel.tolist():
        stop = int(at_seg[n])
        if not held and stop > cur:
            held = not seg.integrate(pim, cur, stop)
            cur = stop
            if not held:
                ns = pim.predict(start, bias)
        poses[n], vel[n] = ns.pose().matrix(), ns.velocity()


def _interval(seg, kt, s, params, k, T0, sel, out_ns, at_seg, poses, vel) -> None:
    T1 = nav(s["R"][k + 1], s["p"][k + 1])
    span = (kt[k + 1] - kt[k]) * 1e-9
    c0, c1 = int(seg.at_cut_of(kt[k])), int(seg.at_cut_of(kt[k + 1]))
    if seg.gap[c0:c1].any():  # no IMU: poses and velocities interpolated
        xi = gtsam.Pose3.Logmap(T0.between(T1))
        for n in sel.tolist():
            w = (out_ns[n] - kt[k]) * 1e-9 / span
            poses[n] = T0.compose(gtsam.Pose3.Expmap(w * xi)).matrix()
            vel[n] = (1 - w) * s["v"][k] + w * s["v"][k + 1]
        return
    bias = gtsam.imuBias.ConstantBias(s["ba"][k], s["bg"][k])
    state = gtsam.NavState(gtsam.Rot3(s["R"][k]), s["p"][k], s["v"][k])
    pim = gtsam.PreintegratedCombinedMeasurements(params, bias)
    preds, cur = [], c0
    for n in sel.tolist():
        stop = int(at_seg[n])
        seg.integrate(pim, cur, stop)
        cur = stop
        preds.append((n, pim.predict(state, bias) if pim.deltaTij() > 0 else state))
    seg.integrate(pim, cur, c1)
    end = pim.predict(state, bias)
    miss = gtsam.Pose3.Logmap(end.pose().between(T1))
    dv = s["v"][k + 1] - end.velocity()
    for n, ns in preds:
        w = (out_ns[n] - kt[k]) * 1e-9 / span
        poses[n] = ns.pose().compose(gtsam.Pose3.Expmap(w * miss)).matrix()
        vel[n] = ns.velocity() + w * dv
