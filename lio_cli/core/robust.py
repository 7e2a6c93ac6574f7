"""Robust spread: a normal sigma from the median absolute deviation, what every slip and outlier gate here uses."""

from __future__ import annotations

import numpy as np

MAD_SIGMA = 1.4826  # a normal distribution's sigma per median absolute deviation


def robust_sigma(x: np.ndarray, centre: bool = True) -> float:
    """``MAD_SIGMA`` times the median absolute deviation of ``x`` about its median (``centre``) or about zero."""
    d = x - np.median(x) if centre else x
    return MAD_SIGMA * float(np.median(np.abs(d)))


__all__ = ["MAD_SIGMA", "robust_sigma"]
