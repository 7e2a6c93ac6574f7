"""``np.median`` and ``np.percentile`` (linear) of a 1-D array, to the bit, without importing ``numpy.ma``.

numpy's own import ``numpy.ma`` at their first call (the median's NaN check asks whether its result is masked;
the percentile sorts its partition indices with ``np.unique``), several ms of every run's start-up. These make
the same calls in the same order otherwise: the same partition, mean and interpolation, the same NaN answer.
"""

from __future__ import annotations

import math

import numpy as np


def median(values) -> np.generic | float:
    """``np.median(values)`` of a 1-D array with at least one value (anything else: numpy's own)."""
    a = np.asanyarray(values)
    sz = a.size
    if a.ndim != 1 or sz == 0:
        return np.median(a)
    half = sz // 2
    kth = [half - 1, half] if sz % 2 == 0 else [half]
    nans = np.issubdtype(a.dtype, np.inexact) or a.dtype.kind in "Mm"
    if nans:
        kth.append(-1)
    part = np.partition(a, kth, axis=None)
    result = np.mean(part[half - 1:half + 1] if sz % 2 == 0 else part[half:half + 1], axis=0)
    if nans and np.isnan(part[-1]):
        return part[-1]
    return result


def percentile(values, q: float) -> np.generic | float:
    """``np.percentile(values, q)`` (linear) of a 1-D array with at least one value, ``q`` a number in [0, 100]
    (anything else: numpy's own)."""
    a = np.asanyarray(values)
    if a.ndim != 1 or a.size == 0 or type(q) not in (int, float) or not 0 <= q <= 100 or a.dtype.kind not in "iuf":
        return np.percentile(a, q)
    arr = a.flatten()
    n = arr.shape[0]
    virtual = (n - 1) * np.true_divide(q, 100)
    prev = nxt = -1 if virtual >= n - 1 else None
    if prev is None:
        prev = int(math.floor(virtual))
        nxt = prev + 1
    arr.partition(sorted({0, -1, prev, nxt}))
    below, above = arr[prev], arr[nxt]
    gamma = float(np.asanyarray(virtual - np.intp(prev), dtype=np.float64))
    diff = above - below
    result = np.add(below, diff * gamma, out=...)
    np.subtract(above, diff * (1 - gamma), out=result, where=gamma >= 0.5, casting="unsafe",
                dtype=type(result.dtype))
    result = result[()]
    if a.dtype.kind == "f" and np.isnan(arr[-1]):
        return arr[-1]
    return result


__all__ = ["median", "percentile"]
