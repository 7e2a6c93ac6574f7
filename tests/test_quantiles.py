"""``quantiles``: numpy's median and linear percentile to the bit (value and type), without numpy.ma."""

from __future__ import annotations

import subprocess
import sys
import warnings
from pathlib import Path

import numpy as np
import pytest

from lio_cli.quantiles import median, percentile

ROOT = Path(__file__).resolve().parents[1]


def _same(got, want) -> bool:
    return type(got) is type(want) and np.asarray(got).tobytes() == np.asarray(want).tobytes()


def _arrays(rng: np.random.Generator):
    for n in (1, 2, 3, 4, 5, 10, 11, 256, 1001):
        for dtype in ("f8", "f4"):
            x = (rng.standard_normal(n) * 10.0 ** rng.integers(-3, 6)).astype(dtype)
            yield x
            yield np.round(x)  # ties
            if n > 1:
                y = x.copy()
                y[rng.integers(n)] = np.nan
                yield y
                y = x.copy()
                y[rng.integers(n)] = np.inf
                yield y
        for dtype in ("i8", "i4", "u2"):
            yield rng.integers(0, 1000, n).astype(dtype)


def test_median_and_percentile_are_numpys_to_the_bit():
    rng = np.random.default_rng(0)
    checked = 0
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)
        for x in _arrays(rng):
            assert _same(median(x), np.median(x.copy()))
            for q in (0, 5, 50, 90, 95, 100, 12.5, 99.9, float(rng.uniform(0, 100))):
                assert _same(percentile(x, q), np.percentile(x.copy(), q)), (x.dtype, len(x), q)
                checked += 1
    assert checked > 800


def test_inputs_are_left_as_they_were_and_odd_inputs_go_to_numpy():
    x = np.array([3.0, 1.0, 2.0, 5.0, 4.0])
    median(x), percentile(x, 95)
    assert x.tolist() == [3.0, 1.0, 2.0, 5.0, 4.0]
    assert median([1.0, 2.0]) == 1.5 and percentile([1, 2, 3, 4], 50) == 2.5
    m = np.arange(12.0).reshape(3, 4)  # not 1-D: numpy's own, whole-array
    assert median(m) == np.median(m) and percentile(m, 90) == np.percentile(m, 90)
    with pytest.raises(ValueError, match="Percentiles must be in the range"):
        percentile(x, 101)


def test_numpy_ma_is_not_imported():
    code = ("import sys, numpy as np\nfrom lio_cli.quantiles import median, percentile\n"
            "x = np.array([3.0, np.nan, 1.0, 2.0])\nmedian(x); median(np.arange(6)); percentile(x, 95); "
            "percentile(np.arange(7.0), 90)\nprint('numpy.ma' in sys.modules)")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True, cwd=ROOT)
    assert out.stdout.strip() == "False"
