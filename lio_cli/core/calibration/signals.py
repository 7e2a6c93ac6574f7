"""Continuous-time views of sampled IMU signals: the gyro's orientation at any instant, and exact integrals of
a piecewise-linear signal (interval means, and averages against a hat kernel, which is what the second
divided difference of a position measures of its acceleration).

Times here are float seconds relative to the first sample's stamp (``t0_ns``), on the IMU's clock.
"""

from __future__ import annotations

import numpy as np

from ...geometry import cross_rows, so3_exp
from .common import NS_PER_S


def prefix_products(steps: np.ndarray) -> np.ndarray:
    """Running products ``steps[0] @ ... @ steps[k]`` of (n,3,3) matrices, in log2(n) vectorised passes."""
    out = steps.copy()
    k = 1
    while k < len(out):
        out[k:] = out[:-k] @ out[k:]
        k *= 2
    return out


class GyroOrientation:
    """Orientation ``G(t)`` of the IMU relative to its first sample, from the gyro alone (trapezoid rule:
    each step turns by ``0.5 (w_k + w_k+1) dt``, which keeps the timing unbiased); between samples the step's
    rotation vector is scaled linearly."""

    def __init__(self, stamps_ns: np.ndarray, gyro_radps: np.ndarray, bias_radps: np.ndarray | None = None) -> None:
        self.t0_ns = int(stamps_ns[0])
        self.t_s = (np.asarray(stamps_ns, np.int64) - self.t0_ns) / NS_PER_S
        w = np.asarray(gyro_radps, np.float64) - (0.0 if bias_radps is None else np.asarray(bias_radps, np.float64))
        dt = np.diff(self.t_s)
        self.phi = 0.5 * (w[:-1] + w[1:]) * dt[:, None]
        G = np.empty((len(self.t_s), 3, 3))
        G[0] = np.eye(3)
        G[1:] = prefix_products(so3_exp(self.phi))
        self.G = G

    def relative_s(self, lidar_stamps_ns: np.ndarray, imu_time_offset_s: float) -> np.ndarray:
        """IMU-clock seconds (relative to ``t0_ns``) of LiDAR-clock stamps: t_imu = t_lidar - offset."""
        return (np.asarray(lidar_stamps_ns, np.int64) - self.t0_ns) / NS_PER_S - imu_time_offset_s

    def at(self, t_s: np.ndarray) -> np.ndarray:
        """G at IMU-clock times ``t_s`` (clamped to the samples' span) -> (n,3,3)."""
        k, phi = self._locate(t_s)
        return self.G[k] @ so3_exp(phi)

    def _locate(self, t_s: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(sample before each time, the rotation vector from that sample to the time), times clamped."""
        t = np.clip(np.asarray(t_s, np.float64), self.t_s[0], self.t_s[-1])
        k = np.clip(np.searchsorted(self.t_s, t, side="right") - 1, 0, len(self.t_s) - 2)
        return k, self.phi[k] * ((t - self.t_s[k]) / (self.t_s[k + 1] - self.t_s[k]))[:, None]

    def rotate(self, t_s: np.ndarray, v: np.ndarray) -> np.ndarray:
        """``G(t) v`` for vectors ``v`` (n,3) at IMU-clock times ``t_s`` (n,), as ``at`` but without forming a
        matrix per vector (Rodrigues on the vectors: many points, few samples)."""
        k, phi = self._locate(t_s)
        theta = np.sqrt(np.einsum("ni,ni->n", phi, phi))
        small = theta < 1e-6
        th = np.where(small, 1.0, theta)
        a = np.where(small, 1.0 - theta**2 / 6.0, np.sin(th) / th)
        b = np.where(small, 0.5 - theta**2 / 24.0, (1.0 - np.cos(th)) / th**2)
        c = cross_rows(phi, v)
        w = v + a[:, None] * c + b[:, None] * cross_rows(phi, c)
        return np.einsum("nij,nj->ni", self.G[k], w)

    def increments(self, ta_s: np.ndarray, tb_s: np.ndarray) -> np.ndarray:
        """Rotation G(ta)^T G(tb) of each interval -> (n,3,3)."""
        return np.swapaxes(self.at(ta_s), 1, 2) @ self.at(tb_s)


class PiecewiseLinear:
    """A signal sampled at ``t_s`` (increasing) and linear in between, with its first and second integrals
    evaluated exactly at any time inside the span (its mean is taken out first to keep the integrals small)."""

    def __init__(self, t_s: np.ndarray, values: np.ndarray) -> None:
        self.t = np.asarray(t_s, np.float64)
        v = np.asarray(values, np.float64)
        self.shape = v.shape[1:]
        v = v.reshape(len(self.t), -1)
        self.mean = v.mean(axis=0)
        self.v = v - self.mean
        h = np.diff(self.t)[:, None]
        self.h = h
        self.S1 = np.concatenate([np.zeros((1, v.shape[1])), np.cumsum(0.5 * (self.v[1:] + self.v[:-1]) * h, axis=0)])
        seg2 = self.S1[:-1] * h + self.v[:-1] * h**2 / 2 + (self.v[1:] - self.v[:-1]) * h**2 / 6
        self.S2 = np.concatenate([np.zeros((1, v.shape[1])), np.cumsum(seg2, axis=0)])

    def _locate(self, t_s: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        t = np.clip(np.asarray(t_s, np.float64), self.t[0], self.t[-1])
        k = np.clip(np.searchsorted(self.t, t, side="right") - 1, 0, len(self.t) - 2)
        return t, k, (t - self.t[k])[:, None]

    def integral(self, t_s: np.ndarray) -> np.ndarray:
        """First integral of the mean-removed signal from the first sample -> (n, ...)."""
        t, k, tau = self._locate(t_s)
        f0, f1, h = self.v[k], self.v[k + 1], self.h[k]
        out = self.S1[k] + f0 * tau + (f1 - f0) * tau**2 / (2 * h)
        return out.reshape((len(t),) + self.shape)

    def double_integral(self, t_s: np.ndarray) -> np.ndarray:
        """Second integral of the mean-removed signal -> (n, ...)."""
        t, k, tau = self._locate(t_s)
        f0, f1, h = self.v[k], self.v[k + 1], self.h[k]
        out = self.S2[k] + self.S1[k] * tau + f0 * tau**2 / 2 + (f1 - f0) * tau**3 / (6 * h)
        return out.reshape((len(t),) + self.shape)

    def interval_mean(self, ta_s: np.ndarray, tb_s: np.ndarray) -> np.ndarray:
        """Mean of the signal over each [ta, tb] -> (n, ...)."""
        d = (np.asarray(tb_s, np.float64) - np.asarray(ta_s, np.float64)).reshape((-1,) + (1,) * len(self.shape))
        return (self.integral(tb_s) - self.integral(ta_s)) / d + self.mean.reshape(self.shape)

    def hat_average(self, ta_s: np.ndarray, tb_s: np.ndarray, tc_s: np.ndarray) -> np.ndarray:
        """Average of the signal weighted by the hat kernel on [ta, tc] peaking at tb (unit area) -> (n, ...).

        Equals twice the second divided difference of the signal's second integral, so a position's second
        divided difference over stamps ta < tb < tc is exactly the hat average of its acceleration."""
        return second_divided_difference(self.double_integral(ta_s), self.double_integral(tb_s),
                                         self.double_integral(tc_s), ta_s, tb_s, tc_s) + self.mean.reshape(self.shape)


def second_divided_difference(xa: np.ndarray, xb: np.ndarray, xc: np.ndarray, ta_s: np.ndarray, tb_s: np.ndarray,
                              tc_s: np.ndarray) -> np.ndarray:
    """2 x[ta, tb, tc]: the hat-kernel average of x'' over [ta, tc] (x (n, ...), times (n,))."""
    ta, tb, tc = (np.asarray(t, np.float64).reshape((-1,) + (1,) * (np.ndim(xa) - 1)) for t in (ta_s, tb_s, tc_s))
    return 2.0 / (tc - ta) * ((xc - xb) / (tc - tb) - (xb - xa) / (tb - ta))
