"""Robust spread: a normal sigma from the median absolute deviation, what every slip and outlier gate here uses."""

from __future__ import annotations

import numpy as np

MAD_SIGMA = 1.4826  # a normal distribution's sigma per median absolute deviation


def robust_sigma(x: np.ndarray, centre: bool = True) -> float:
    """``MAD_SIGMA`` times the median absolute deviation of ``x`` about its median (``centre``) or about zero."""
    d = x - np.median(x) if centre else x
    return MAD_SIGMA * float(np.median(np.abs(d)))


def white_variance(x: np.ndarray, keep: np.ndarray | None = None) -> float:
    """The per-sample variance of ``x``'s white noise from its second differences (``6 sigma^2`` for white noise,
    a smooth signal adds little), robustly; ``keep`` (one per second difference) selects those used."""
    d2 = x[2:] - 2.0 * x[1:-1] + x[:-2]
    return robust_sigma(d2 if keep is None else d2[keep], centre=False) ** 2 / 6.0


__all__ = ["MAD_SIGMA", "robust_sigma"]
