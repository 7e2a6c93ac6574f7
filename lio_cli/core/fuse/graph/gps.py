"""GPS in the factor graph: each fix on its keyframe, horizontal (Huber) and vertical (Cauchy) as two factors, so a
wandering altitude never down-weights a good horizontal fix, plus a slowly varying receiver error (``G``: one 3D
node per fix, a first-order Gauss-Markov chain of correlation time ``GPS_BIAS_TAU_S`` and ``GPS_BIAS_RATIO`` times
the fixes' sigma). Horizontally the chain is on beside odometry (without it, pinned at zero); vertically always,
except where the height prior holds the odometry's height (``height``): there the vertical fix stays white.
"""

from __future__ import annotations

import gtsam
import numpy as np
from gtsam.symbol_shorthand import G, X

from ..state3d import skew3
from .keyframes import MERGE_NS, attach

HUBER_K = 2.5  # whitened norm of a 2D residual: about its 95th percentile, so good fixes keep their weight
CAUCHY_K = 1.0  # vertical GPS: an altitude wander is a run of outliers
GPS_BIAS_PERIOD_NS = 5_000_000_000  # the guard's windows of the receiver error (guard.residuals)
GPS_BIAS_TAU_S = 60.0  # correlation time of a receiver's slow error (multipath, atmosphere, satellite geometry)
# its sigma over the fixes' own (the timeline's) horizontal sigma: consumer receivers claim a third of the truth,
# and the chain must leave the shape over seconds to the motion sources
GPS_BIAS_RATIO = 10.0
PINNED_SIGMA_M = 1e-4  # a receiver-error axis held at zero (the horizontal one without odometry)
# beside odometry (where the receiver-error chain is on), the fixes' vertical sigma times this
ODOM_GPS_VERTICAL_SCALE = 3.0
FREE_SIGMA = 1e4  # an axis a factor leaves out (metres)


def _accepted(g) -> np.ndarray:
    """The filter's GPS gating when the prepared timeline carries it (``accepted``), else every fix."""
    acc = getattr(g, "accepted", None)
    return np.ones(len(g), bool) if acc is None else np.asarray(acc, bool)


def gps_sigmas(g, idx: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Horizontal and vertical sigma per fix: the timeline's own where it has them, else the fix covariance."""
    h, v = getattr(g, "sigma_h_m", None), getattr(g, "sigma_v_m", None)
    if h is not None and v is not None:
        return np.asarray(h, float)[idx], np.asarray(v, float)[idx]
    c = g.cov_m2[idx]
    return np.sqrt(0.5 * (c[:, 0, 0] + c[:, 1, 1])), np.sqrt(c[:, 2, 2])


def _fix_axes(z: np.ndarray, axes: slice, lever: np.ndarray | None = None):
    """A CustomFactor's error function: the antenna's position on ``axes`` (horizontal 0:2, vertical 2:3; the
    keyframe's pose moved by ``lever``, base axes) plus the receiver error there (a second key) minus the fix."""
    a = np.zeros(3) if lever is None else np.asarray(lever, float)
    skew = skew3(a)

    def error(this, values, H):
        keys = this.keys()
        T = values.atPose3(keys[0])
        R = T.rotation().matrix()
        b = values.atPoint3(keys[1]) if len(keys) > 1 else np.zeros(3)
        if H is not None:
            H[0] = np.hstack([(-R @ skew)[axes, :], R[axes, :]])
            if len(keys) > 1:
                H[1] = np.eye(3)[axes, :]
        return T.translation()[axes] + (R @ a)[axes] + b[axes] - z
    return error


def _markov_step(phi: float):
    """A CustomFactor's error function: the next receiver error minus ``phi`` times the previous one."""
    def error(this, values, H):
        a, b = values.atPoint3(this.keys()[0]), values.atPoint3(this.keys()[1])
        if H is not None:
            H[0] = -phi * np.eye(3)
            H[1] = np.eye(3)
        return b - phi * a
    return error


def attach_fixes(m, prep, kt: np.ndarray) -> None:
    """The accepted fixes within the keyframes' span as ``m.gps_*`` (keyframe, ENU about the first fix, sigmas, the
    guard's window, seconds) and the receiver-error chain's sigmas (zero: no chain on that axis)."""
    m.gps_k = m.gps_j = np.zeros(0, np.int64)
    m.gps_bias_sigma = m.gps_bias_sigma_v = 0.0  # the receiver-error chain's, horizontal and vertical
    m.gps_lever = None  # the antenna on the base (base axes), None at its origin
    g = prep.gps
    if g is not None and len(g) and "gps" in prep.use:
        ok = (g.stamps_ns >= kt[0]) & (g.stamps_ns < kt[-1] + MERGE_NS) & _accepted(g)
        idx = np.flatnonzero(ok)
        first = np.flatnonzero((g.stamps_ns >= kt[0]) & (g.stamps_ns < kt[-1] + MERGE_NS))
        if len(idx):
            m.gps_idx = idx
            m.gps_k = attach(kt, g.stamps_ns[idx])
            m.gps_origin_m = g.position_enu_m[first[0]]  # the filter's anchor
            m.gps_z = g.position_enu_m[idx] - m.gps_origin_m
            m.gps_h, m.gps_v = gps_sigmas(g, idx)
            m.gps_j = (g.stamps_ns[idx] - kt[0]) // GPS_BIAS_PERIOD_NS  # the guard's window per fix
            m.gps_t_s = (g.stamps_ns[idx] - kt[0]) * 1e-9
            m.gps_lever = g.lever
            # horizontally only beside odometry: without it the chain measured mixed (docs/benchmarks.md)
            if prep.odom is not None and "odom" in prep.use:
                m.gps_bias_sigma = GPS_BIAS_RATIO * float(np.median(m.gps_h))
                m.gps_bias_sigma_v = GPS_BIAS_RATIO * ODOM_GPS_VERTICAL_SCALE * float(np.median(m.gps_v))
            else:
                m.gps_bias_sigma_v = GPS_BIAS_RATIO * float(np.median(m.gps_v))


def add_fixes(g, m, level, nodes: np.ndarray, bias_seam: dict[int, np.ndarray], k0: int, k1: int) -> None:
    """The fixes on keyframes [k0, k1) (``nodes``: their receiver-error nodes) and the chain between the nodes;
    ``level``: the height prior, beside which the vertical fix stays white; ``bias_seam``: the previous chunk's
    solved nodes."""
    huber = gtsam.noiseModel.mEstimator.Huber.Create(HUBER_K)
    cauchy = gtsam.noiseModel.mEstimator.Cauchy.Create(CAUCHY_K)
    sel = np.flatnonzero((m.gps_k >= k0) & (m.gps_k < k1))
    for j in sel.tolist():
        k, z, h, v = int(m.gps_k[j]), m.gps_z[j], float(m.gps_h[j]), float(m.gps_v[j])
        if m.gps_bias_sigma > 0:  # beside odometry: its increments carry the height, the altitude wanders
            v *= ODOM_GPS_VERTICAL_SCALE
        a = m.gps_lever
        keys = [X(k), G(j)] if m.gps_bias_sigma_v > 0 else [X(k)]
        vkeys = keys if level is None else [X(k)]  # with a height prior the vertical fix stays white
        if len(keys) > 1 or a is not None:
            nh = gtsam.noiseModel.Robust.Create(huber, gtsam.noiseModel.Isotropic.Sigma(2, h))
            g.add(gtsam.CustomFactor(nh, keys, _fix_axes(z[:2], slice(0, 2), a)))
        else:
            nh = gtsam.noiseModel.Diagonal.Sigmas(np.array([h, h, FREE_SIGMA]))
            g.add(gtsam.GPSFactor(X(k), z, gtsam.noiseModel.Robust.Create(huber, nh)))
        if len(vkeys) > 1 or a is not None:
            nv = gtsam.noiseModel.Robust.Create(cauchy, gtsam.noiseModel.Isotropic.Sigma(1, v))
            g.add(gtsam.CustomFactor(nv, vkeys, _fix_axes(z[2:], slice(2, 3), a)))
        else:
            nv = gtsam.noiseModel.Diagonal.Sigmas(np.array([FREE_SIGMA, FREE_SIGMA, v]))
            g.add(gtsam.GPSFactor(X(k), z, gtsam.noiseModel.Robust.Create(cauchy, nv)))
    if not len(nodes):
        return
    sh = m.gps_bias_sigma if m.gps_bias_sigma > 0 else PINNED_SIGMA_M
    sb, t = np.r_[sh, sh, m.gps_bias_sigma_v], m.gps_t_s
    for a, b in zip(nodes[:-1].tolist(), nodes[1:].tolist()):  # Gauss-Markov steps over the fixes' spacing
        phi = float(np.exp(-(t[b] - t[a]) / GPS_BIAS_TAU_S))
        step = gtsam.noiseModel.Diagonal.Sigmas(sb * float(np.sqrt(max(1.0 - phi * phi, 1e-12))))
        g.add(gtsam.CustomFactor(step, [G(a), G(b)], _markov_step(phi)))
    first = int(nodes[0])
    if first in bias_seam:  # the previous chunk's value, as loose as the error moves in a few seconds
        seam = sb * float(np.sqrt(1.0 - np.exp(-2.0 * GPS_BIAS_PERIOD_NS * 1e-9 / GPS_BIAS_TAU_S)))
        g.add(gtsam.PriorFactorPoint3(G(first), bias_seam[first], gtsam.noiseModel.Diagonal.Sigmas(seam)))
    else:
        g.add(gtsam.PriorFactorPoint3(G(first), np.zeros(3), gtsam.noiseModel.Diagonal.Sigmas(sb)))


__all__ = ["add_fixes", "attach_fixes", "gps_sigmas"]
