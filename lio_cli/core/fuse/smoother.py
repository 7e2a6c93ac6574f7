"""Offline Rauch-Tung-Striebel smoother over a filter's knots, in error-state form.

Backwards from the last knot: ``G_k = P_k|k Phi_k+1^T P_k+1|k^-1``, the smoothed correction at k+1
expressed against its prediction ``d = x_k+1|N [-] x_k+1|k``, then ``x_k|N = x_k|k [+] G_k d`` and
``P_k|N = P_k|k + G_k (P_k+1|N - P_k+1|k) G_k^T``. On a linear-Gaussian model this equals the batch
least-squares solution over all measurements before and after each instant.
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np

from ...errors import ProcessingError


class SingularPrediction(ProcessingError):
    """A knot's predicted covariance cannot be inverted."""


def rts_smooth(knots: dict[str, np.ndarray], boxplus: Callable[[np.ndarray, np.ndarray], None],
               boxminus: Callable[[np.ndarray, np.ndarray], np.ndarray]) -> tuple[np.ndarray, np.ndarray]:
    """Smoothed states and covariances at every knot of a ``KnotLog(for_smoother=True).arrays()``."""
    xf, Pf, xp, Pp, Phi = knots["x_filt"], knots["P_filt"], knots["x_pred"], knots["P_pred"], knots["Phi"]
    K = len(xf)
    xs, Ps = xf.copy(), Pf.copy()
    for k in range(K - 2, -1, -1):
        try:
            G = np.linalg.solve(Pp[k + 1], Phi[k + 1] @ Pf[k]).T
        except np.linalg.LinAlgError as err:
            raise SingularPrediction(f"smoother: predicted covariance singular at knot {k + 1} of {K}") from err
        d = boxminus(xs[k + 1], xp[k + 1])
        x = xf[k].copy()
        boxplus(x, G @ d)
        xs[k] = x
        P = Pf[k] + G @ (Ps[k + 1] - Pp[k + 1]) @ G.T
        Ps[k] = 0.5 * (P + P.T)
    return xs, Ps
