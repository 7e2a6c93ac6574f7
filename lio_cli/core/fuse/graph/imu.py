"""The IMU between keyframes: GTSAM's combined preintegration (rotation, velocity, position and both biases'
random walks), fed the base-frame rate and specific force (``timeline.Prepared.imu_w_b``/``imu_f_b``: lever arm
already removed) at the midpoint of each IMU interval, as the filter steps.

The time axis is cut at every IMU stamp and every stamp in ``cuts`` (keyframes, outputs); a segment inside an
IMU gap (longer than ``Prepared.imu_gap_ns``) or outside the IMU's data is marked, so the interval holding it
gets no IMU factor (the caller bridges it).
"""

from __future__ import annotations

import gtsam
import numpy as np

from ..inputs import NoiseOptions
from ..timeline import Prepared

INTEGRATION_SIGMA = 1e-4  # position integration error per sqrt(s): GTSAM's usual small regulariser
BIAS_INIT_SIGMA = 1e-5


def imu_params(noise: NoiseOptions, gravity_mps2: float) -> gtsam.PreintegrationCombinedParams:
    p = gtsam.PreintegrationCombinedParams.MakeSharedU(gravity_mps2)
    eye = np.eye(3)
    p.setAccelerometerCovariance(eye * noise.accel_noise_density**2)
    p.setGyroscopeCovariance(eye * noise.gyro_noise_density**2)
    p.setIntegrationCovariance(eye * INTEGRATION_SIGMA**2)
    p.setBiasAccCovariance(eye * noise.accel_bias_walk**2)
    p.setBiasOmegaCovariance(eye * noise.gyro_bias_walk**2)
    if hasattr(p, "setBiasAccOmegaInit"):
        p.setBiasAccOmegaInit(np.eye(6) * BIAS_INIT_SIGMA**2)
    return p


class Segments:
    """The time axis between ``cuts[0]`` and ``cuts[-1]`` cut at IMU stamps and ``cuts``: per segment its start
    (ns), length (s), the IMU interval's midpoint rate and force, and whether it lies in an IMU gap; ``at_cut[j]``
    is the first segment starting at or after ``cuts[j]``."""

    def __init__(self, prep: Prepared, cuts: np.ndarray):
        st = prep.imu.stamps_ns
        a, b = int(cuts[0]), int(cuts[-1])
        inner = st[(st > a) & (st < b)]
        edges = np.unique(np.concatenate([inner, cuts]))
        self.t = edges[:-1]
        self.dt = np.diff(edges) * 1e-9
        i = np.searchsorted(st, self.t, side="right") - 1  # the IMU interval [st[i], st[i+1]] holding each segment
        ok = (i >= 0) & (i + 1 < len(st))
        ic = np.clip(i, 0, len(st) - 2)
        ok &= (st[ic + 1] - st[ic]) <= prep.imu_gap_ns
        self.gap = ~ok
        w, f = prep.imu_w_b, prep.imu_f_b
        self.w = 0.5 * (w[ic] + w[ic + 1])
        self.f = 0.5 * (f[ic] + f[ic + 1])
        self.at_cut = np.searchsorted(self.t, cuts)

    def at_cut_of(self, t_ns: int) -> int:
        """The first segment starting at or after ``t_ns`` (one past the last at the end)."""
        return int(np.searchsorted(self.t, t_ns))

    def integrate(self, pim, s0: int, s1: int) -> bool:
        """Integrate segments [s0, s1) into ``pim``; False (nothing integrated) when one lies in a gap."""
        if self.gap[s0:s1].any():
            return False
        for f, w, dt in zip(self.f[s0:s1], self.w[s0:s1], self.dt[s0:s1].tolist()):
            pim.integrateMeasurement(f, w, dt)
        return True

    def integrate_with(self, pim, s0: int, s1: int, wheel=None) -> tuple[np.ndarray | None, np.ndarray | None]:
        """``integrate`` (no gap inside) and, with a ``factors.WheelTrack``, the wheel increment over the same
        segments in the first one's base axes, rotated by the gyro as integrated: ``sum dR v dt`` and its sigma
        per axis, ``sum sigma dt``: the wheels' errors (scale, slip) hold over an interval, they do not average out."""
        if wheel is None:
            self.integrate(pim, s0, s1)
            return None, None
        dp, sd = np.zeros(3), np.zeros(3)
        for s in range(s0, s1):
            dt = float(self.dt[s])
            R = pim.deltaRij().matrix() if s > s0 else np.eye(3)
            dp += R @ wheel.z[s] * dt
            sd += wheel.sigma[s] * dt
            pim.integrateMeasurement(self.f[s], self.w[s], dt)
        return dp, sd
