"""Allan deviation of a static IMU log and the noise parameters read from it.

The overlapping Allan variance of a rate signal sampled every ``dt`` at cluster size ``m`` (tau = m dt) is
``sum_k (th[k+2m] - 2 th[k+m] + th[k])^2 / (2 tau^2 (n - 2m + 1))`` with ``th`` the running integral of the
rate: one cumulative sum, then O(n) per tau for log-spaced taus.

Noise model (IEEE 952; the definitions of lio's simulator and of Kalibr):
- white noise, density ``N`` (rad/s/sqrt(Hz) or m/s^2/sqrt(Hz); discrete std = N sqrt(rate)): AVAR = N^2 / tau,
  the slope -1/2 line of the deviation, read at tau = 1 s;
- bias random walk, density ``K`` (rad/s^2/sqrt(Hz) or m/s^3/sqrt(Hz); bias steps of std K sqrt(dt)):
  AVAR = K^2 tau / 3, the slope +1/2 line, read at tau = 3 s;
- bias instability ``B`` (flicker): AVAR = (2 ln 2 / pi) B^2, flat; reported the usual way, as the minimum of
  the deviation / 0.664.

Reading each line off where it looks straight comes out low (the curve bends away from both lines near its
minimum, and where one term is read the others are not zero). Here the three terms are fitted together to the
whole curve: a non-negative least squares in AVAR, weighted by each point's variance (its equivalent degrees
of freedom, Howe et al.), iterated because that variance depends on the model. The fitted local slopes are
reported from the taus where each term dominates.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.optimize import nnls

from ...errors import InputError
from .common import NS_PER_S, CalibrationResult, check_imu
from .imu_static import StillOptions, moving_share

FLICKER_AVAR = 2.0 * np.log(2.0) / np.pi  # AVAR of bias instability B is FLICKER_AVAR * B^2
BIAS_INSTABILITY_FACTOR = 0.664  # sqrt(FLICKER_AVAR)
DOMINANT_SHARE = 0.8  # a term "dominates" a tau where it holds this share of the model AVAR
MIN_SLOPE_POINTS = 4
MIN_DURATION_S = 60.0


@dataclass(frozen=True, eq=False)
class AllanFit(CalibrationResult):
    """Noise parameters of one sensor (3 axes). Densities as in the module doc. Sigmas are the Cramer-Rao
    bound of the log's length (no estimator does better; the fit's own scatter is larger). A slope is NaN (and
    its tau range NaN) when its term dominates too few taus to fit one."""

    noise_density: np.ndarray  # per axis
    noise_density_sigma: np.ndarray
    random_walk: np.ndarray
    random_walk_sigma: np.ndarray
    noise_density_mean: float  # the three axes averaged (what Kalibr's single value takes)
    noise_density_mean_sigma: float
    random_walk_mean: float
    random_walk_mean_sigma: float
    bias_instability: np.ndarray  # min deviation / 0.664
    bias_instability_tau_s: np.ndarray  # where the minimum is
    white_slope: np.ndarray  # fitted log-log slope where white noise dominates (ideal -0.5)
    white_tau_range_s: np.ndarray  # (3,2)
    random_walk_slope: np.ndarray  # ideal +0.5
    random_walk_tau_range_s: np.ndarray  # (3,2)
    model_avar: np.ndarray  # (3,3): per axis the fitted [N^2, FLICKER_AVAR * B_fit^2, K^2]


@dataclass(frozen=True, eq=False)
class AllanResult(CalibrationResult):
    rate_hz: float
    duration_s: float
    taus_s: np.ndarray  # (m,)
    gyro_adev_radps: np.ndarray  # (m,3)
    accel_adev_mps2: np.ndarray  # (m,3)
    clusters: np.ndarray  # (m,) number of overlapping cluster pairs behind each point
    gyro: AllanFit
    accel: AllanFit
    notes: tuple[str, ...]


def allan_deviation(rate: np.ndarray, dt_s: float, points_per_decade: int = 12) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(taus_s (m,), overlapping Allan deviation (m, k), cluster counts (m,)) of rate samples (n, k)."""
    x = np.asarray(rate, np.float64)
    n = len(x)
    th = np.zeros((x.shape[1], n + 1))  # axes in rows: contiguous passes
    np.cumsum((x - x.mean(axis=0)).T, axis=1, out=th[:, 1:])
    m_max = max(1, (n - 1) // 3)  # at least as many overlapping pairs as the cluster is long
    count = max(2, int(np.log10(m_max) * points_per_decade) + 1)
    ms = np.unique(np.round(np.logspace(0.0, np.log10(m_max), count)).astype(np.int64))
    ms = ms[(ms >= 1) & (ms <= m_max)]
    avar = np.empty((len(ms), x.shape[1]))
    d = np.empty_like(th)
    for j, m in enumerate(ms):
        # overlapping differences a small fraction of a cluster apart are nearly the same number: past m = 8,
        # every (m // 8)-th start is enough (the estimate's variance grows by well under 1%)
        step = max(1, int(m) // 8)
        k = (n - 2 * m) // step + 1
        dj = d[:, :k]
        np.subtract(th[:, 2 * m::step][:, :k], th[:, m::step][:, :k], out=dj)
        dj -= th[:, m::step][:, :k]
        dj += th[:, :k * step:step][:, :k]
        avar[j] = np.einsum("ij,ij->i", dj, dj) / (2.0 * m * m * k)  # th in samples: tau^2 = m^2 dt^2
    return ms * dt_s, np.sqrt(avar), n + 1 - 2 * ms


def _edf(n_phase: int, m: np.ndarray) -> np.ndarray:
    """Equivalent degrees of freedom of the overlapping AVAR at cluster sizes m for white-FM, flicker-FM
    and random-walk-FM noise (Howe, Allan, Barnes 1981), columns in that order; N phase points."""
    N = float(n_phase)
    m = m.astype(np.float64)
    white = (3 * (N - 1) / (2 * m) - 2 * (N - 2) / N) * 4 * m**2 / (4 * m**2 + 5)
    flicker = np.where(m == 1, 2 * (N - 2) ** 2 / (2.3 * N - 4.9), 5 * N**2 / (4 * m * (N + 3 * m)))
    walk = (N - 2) / m * ((N - 1) ** 2 - 3 * m * (N - 1) + 4 * m**2) / (N - 3) ** 2
    return np.maximum(np.column_stack([white, flicker, walk]), 1.0)


def fit_noise_model(taus_s: np.ndarray, avar: np.ndarray, edf: np.ndarray, iterations: int = 12) -> tuple[np.ndarray, np.ndarray]:
    """Non-negative [N^2, FLICKER_AVAR B^2, K^2] of AVAR = N^2/tau + c + K^2 tau/3 and its covariance (3,3).

    Each point's variance is 2 (sum_j a_j / sqrt(edf_j))^2 with a_j the model's terms there."""
    X = np.column_stack([1.0 / taus_s, np.ones_like(taus_s), taus_s / 3.0])
    scale = np.array([avar[0] * taus_s[0], avar.min(), avar[-1] * 3.0 / taus_s[-1]])
    Xs = X * scale  # unknowns of order one
    w = 1.0 / avar**2
    p = np.zeros(3)
    for _ in range(iterations):
        sw = np.sqrt(w)
        p, _ = nnls(Xs * sw[:, None], avar * sw)
        terms = np.maximum(Xs * p, 1e-300)
        var = 2.0 * (terms / np.sqrt(edf)).sum(axis=1) ** 2
        w = 1.0 / var
    H = (Xs * w[:, None]).T @ Xs
    cov = np.linalg.pinv(H) * np.outer(scale, scale)
    return p * scale, cov


def spectral_covariance(p: np.ndarray, n: int, dt_s: float) -> np.ndarray:
    """Covariance (3,3) of [N^2, FLICKER_AVAR B^2, K^2] at the Cramer-Rao bound of ``n`` samples every ``dt_s``
    (Whittle information of the spectrum S(f) = N^2 + B^2 / (2 pi f) + K^2 / (2 pi f)^2 at the Fourier
    frequencies); terms fitted as zero are held there."""
    f = np.arange(1, n // 2 + 1) / (n * dt_s)
    w = 2.0 * np.pi * f
    D = np.stack([np.ones_like(f), 1.0 / (FLICKER_AVAR * w), 1.0 / w**2])
    S = p @ D
    active = p > 0
    Da = D[active] / S
    cov = np.zeros((3, 3))
    cov[np.ix_(active, active)] = np.linalg.pinv(Da @ Da.T)
    return cov


def _slope(taus_s: np.ndarray, adev: np.ndarray, sel: np.ndarray) -> tuple[float, np.ndarray]:
    if sel.sum() < MIN_SLOPE_POINTS:
        return float("nan"), np.array([np.nan, np.nan])
    lt, la = np.log10(taus_s[sel]), np.log10(adev[sel])
    return float(np.polyfit(lt, la, 1)[0]), np.array([taus_s[sel][0], taus_s[sel][-1]])


def _fit_sensor(taus_s: np.ndarray, adev: np.ndarray, ms: np.ndarray, n_phase: int, dt_s: float, tau_min_s: float) -> AllanFit:
    edf_all = _edf(n_phase, ms)
    use = taus_s >= tau_min_s
    out = {k: [] for k in ("N", "Ns", "K", "Ks", "B", "Bt", "ws", "wr", "rs", "rr", "p")}
    for ax in range(adev.shape[1]):
        a = adev[:, ax] ** 2
        p, _ = fit_noise_model(taus_s[use], a[use], edf_all[use])
        cov = spectral_covariance(p, n_phase - 1, dt_s)
        N, K = np.sqrt(p[0]), np.sqrt(p[2])
        out["N"].append(N)
        out["Ns"].append(0.5 * np.sqrt(cov[0, 0]) / max(N, 1e-300))
        out["K"].append(K)
        out["Ks"].append(0.5 * np.sqrt(cov[2, 2]) / max(K, 1e-300) if K > 0 else np.sqrt(np.sqrt(cov[2, 2])))
        i = int(np.argmin(adev[:, ax]))
        out["B"].append(adev[i, ax] / BIAS_INSTABILITY_FACTOR)
        out["Bt"].append(taus_s[i])
        model = p[0] / taus_s + p[1] + p[2] * taus_s / 3.0
        s, r = _slope(taus_s, adev[:, ax], use & (p[0] / taus_s >= DOMINANT_SHARE * model))
        out["ws"].append(s)
        out["wr"].append(r)
        s, r = _slope(taus_s, adev[:, ax], use & (p[2] * taus_s / 3.0 >= DOMINANT_SHARE * model))
        out["rs"].append(s)
        out["rr"].append(r)
        out["p"].append(p)
    a = {k: np.array(v) for k, v in out.items()}
    return AllanFit(a["N"], a["Ns"], a["K"], a["Ks"], float(a["N"].mean()), float(np.sqrt((a["Ns"] ** 2).sum()) / 3),
                    float(a["K"].mean()), float(np.sqrt((a["Ks"] ** 2).sum()) / 3), a["B"], a["Bt"], a["ws"], a["wr"],
                    a["rs"], a["rr"], a["p"])


def estimate_allan(stamps_ns: np.ndarray, gyro_radps: np.ndarray, accel_mps2: np.ndarray,
                   points_per_decade: int = 12, tau_min_samples: int = 10) -> AllanResult:
    """Allan deviations of gyro and accelerometer and their noise parameters, from a static log.

    ``tau_min_samples``: the shortest tau fitted, in samples (real IMUs low-pass their output, which bends the
    curve at the first few samples)."""
    stamps_ns, gyro_radps, accel_mps2 = check_imu(stamps_ns, gyro_radps, accel_mps2, min_count=100)
    d = np.diff(stamps_ns)
    dt_s = float(np.median(d)) / NS_PER_S
    duration_s = (stamps_ns[-1] - stamps_ns[0]) / NS_PER_S
    if duration_s < max(MIN_DURATION_S, 100 * tau_min_samples * dt_s):
        raise InputError(f"IMU log too short for an Allan deviation ({duration_s:.1f} s at {1 / dt_s:.0f} Hz): "
                         f"record at least a few minutes, ideally hours, standing still")
    notes = []
    gaps = int((d > 1.5 * np.median(d)).sum())
    if gaps:
        notes.append(f"{gaps} gaps in the IMU stamps (dropped samples): the samples are taken as evenly spaced")
    moving = moving_share(stamps_ns, gyro_radps, accel_mps2, StillOptions(window_s=1.0))
    if moving > 0.01:
        notes.append(f"the IMU moves during {100 * moving:.1f}% of the log: Allan deviation needs a static "
                     f"recording, the values are suspect")
    if duration_s < 3600:
        notes.append(f"the log lasts {duration_s / 60:.0f} min: the random walk needs hours (its slope +1/2 shows "
                     f"only at long taus), read it with its uncertainty")
    taus, g_adev, counts = allan_deviation(gyro_radps, dt_s, points_per_decade)
    _, a_adev, _ = allan_deviation(accel_mps2, dt_s, points_per_decade)
    ms = np.round(taus / dt_s).astype(np.int64)
    n_phase = len(stamps_ns) + 1
    gyro = _fit_sensor(taus, g_adev, ms, n_phase, dt_s, tau_min_samples * dt_s)
    accel = _fit_sensor(taus, a_adev, ms, n_phase, dt_s, tau_min_samples * dt_s)
    for name, fit in (("gyro", gyro), ("accelerometer", accel)):
        if np.isnan(fit.random_walk_slope).any():
            notes.append(f"{name}: the random walk dominates too few taus to check its +1/2 slope (log too short)")
    return AllanResult(1.0 / dt_s, duration_s, taus, g_adev, a_adev, counts, gyro, accel, tuple(notes))
