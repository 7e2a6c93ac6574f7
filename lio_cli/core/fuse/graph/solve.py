"""Levenberg-Marquardt over the keyframes in overlapping chunks, so memory stays flat in the log's length.

Chunk c keeps keyframes [c C, (c+1) C) and is solved over ``OVERLAP`` more on each side. Its first keyframe gets
a prior: the filter's start for the first chunk, else the previous chunk's solution there (``seam_prior``; GTSAM's
marginals of a chunk anchored by its prior alone fail as indeterminate on long runs without GPS). Keyframes
within half the overlap of a seam are blended linearly from the two chunks' solutions. Every chunk starts from
the filter's states, so LM only ever lowers the cost from the filter's answer.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field

import gtsam
import numpy as np
from gtsam.symbol_shorthand import B, G, V, X

from .factors import ChunkGraph, nav

CHUNK_KEYFRAMES = 600  # 60 s at the 0.1 s grid
OVERLAP_KEYFRAMES = 100
MAX_ITERATIONS = 40
# damping scaled by the Hessian's diagonal (Marquardt): plain lambda I stalls on chunks mixing very tight and
# loose priors (docs/benchmarks.md, the factor graph against RTS)
DIAGONAL_DAMPING = True
RELATIVE_TOLERANCE = 1e-3  # robust losses reweight slowly: past this the trajectory moves by micrometres


@dataclass
class Prior:
    """Mean and covariance of the nav state at one keyframe (pose tangent [rotation, translation] in body axes)."""
    pose: gtsam.Pose3
    v: np.ndarray
    bias: gtsam.imuBias.ConstantBias
    pose_cov: np.ndarray
    v_cov: np.ndarray
    bias_cov: np.ndarray  # [accel, gyro]


@dataclass
class SolveStats:
    chunks: int = 0
    iterations: int = 0
    initial_error: float = 0.0
    final_error: float = 0.0
    spans: list[tuple[int, int]] = field(default_factory=list)


def chunk_spans(K: int, size: int = CHUNK_KEYFRAMES, overlap: int = OVERLAP_KEYFRAMES
                ) -> list[tuple[int, int, int, int]]:
    """(solve_from, solve_to, keep_from, keep_to) per chunk over K keyframes; the last chunk takes a short tail."""
    n = max(1, int(round(K / size)))
    edges = np.linspace(0, K, n + 1).round().astype(int)
    return [(max(0, a - overlap), min(K, b + overlap), a, b) for a, b in zip(edges[:-1], edges[1:])]


def _add_prior(g: gtsam.NonlinearFactorGraph, k: int, pr: Prior) -> None:
    g.add(gtsam.PriorFactorPose3(X(k), pr.pose, gtsam.noiseModel.Gaussian.Covariance(pr.pose_cov)))
    g.add(gtsam.PriorFactorVector(V(k), pr.v, gtsam.noiseModel.Gaussian.Covariance(pr.v_cov)))
    g.add(gtsam.PriorFactorConstantBias(B(k), pr.bias, gtsam.noiseModel.Gaussian.Covariance(pr.bias_cov)))


def seam_prior(sol: dict[str, np.ndarray], j: int, pose_cov: np.ndarray, v_sigma: float, bias_sigmas: np.ndarray
               ) -> Prior:
    """The previous chunk's solution at its row j as the next chunk's prior, with the filter's pose covariance
    there (information from the past only: the overlap's measurements are not counted twice) and loose velocity
    and bias sigmas (the chunk's own IMU, wheels and GPS find them again within the overlap)."""
    return Prior(nav(sol["R"][j], sol["p"][j]), sol["v"][j], gtsam.imuBias.ConstantBias(sol["ba"][j], sol["bg"][j]),
                 pose_cov, np.eye(3) * v_sigma**2, np.diag(bias_sigmas**2))


def solve(cg: ChunkGraph, K: int, first: Prior, seam: Callable[[dict, int, int], Prior], spans=None
          ) -> tuple[dict[str, np.ndarray], SolveStats]:
    """Smoothed R, p, v, bg, ba at every keyframe (arrays like ``cg.s``) and the solver's counters."""
    spans = spans or chunk_spans(K, CHUNK_KEYFRAMES, OVERLAP_KEYFRAMES)
    out = {k: v.copy() for k, v in cg.s.items()}
    stats = SolveStats(chunks=len(spans))
    prior, prev = first, None
    lm = gtsam.LevenbergMarquardtParams()
    lm.setMaxIterations(MAX_ITERATIONS)
    lm.setRelativeErrorTol(RELATIVE_TOLERANCE)
    lm.setDiagonalDamping(DIAGONAL_DAMPING)
    for c, (s0, s1, a, b) in enumerate(spans):
        g = cg.build(s0, s1)
        _add_prior(g, s0, prior)
        init = cg.values(s0, s1)
        opt = gtsam.LevenbergMarquardtOptimizer(g, init, lm)
        res = opt.optimize()
        stats.iterations += opt.iterations()
        stats.initial_error += g.error(init)
        stats.final_error += g.error(res)
        stats.spans.append((s0, s1))
        sol = _arrays(res, s0, s1)
        if c + 1 < len(spans):
            nxt = spans[c + 1][0]
            prior = seam(sol, nxt - s0, nxt)
            shared = set(cg.gps_bias_nodes(s0, s1).tolist()) & set(cg.gps_bias_nodes(nxt, spans[c + 1][1]).tolist())
            cg.bias_seam = {j: res.atPoint3(G(j)) for j in shared}
        _keep(out, sol, s0, a, b, prev)
        prev = (sol, s0, s1)
    return out, stats


def _arrays(res: gtsam.Values, s0: int, s1: int) -> dict[str, np.ndarray]:
    n = s1 - s0
    o = {"R": np.zeros((n, 3, 3)), "p": np.zeros((n, 3)), "v": np.zeros((n, 3)), "bg": np.zeros((n, 3)),
         "ba": np.zeros((n, 3))}
    for j in range(n):
        k = s0 + j
        T = res.atPose3(X(k))
        o["R"][j], o["p"][j] = T.rotation().matrix(), T.translation()
        o["v"][j] = res.atVector(V(k))
        bb = res.atConstantBias(B(k))
        o["ba"][j], o["bg"][j] = bb.accelerometer(), bb.gyroscope()
    return o


def _keep(out, sol, s0: int, a: int, b: int, prev) -> None:
    """Write keyframes [a, b) of this chunk; blend the seam [a - h, a + h) with the previous chunk's solution."""
    for name in out:
        out[name][a:b] = sol[name][a - s0:b - s0]
    if prev is None:
        return
    psol, p0, p1 = prev
    h = min(OVERLAP_KEYFRAMES // 2, a - s0, p1 - a, b - a)
    for k in range(a - h, a + h):
        w = (k - (a - h) + 0.5) / (2 * h)
        i, j = k - s0, k - p0
        Ta, Tb = nav(psol["R"][j], psol["p"][j]), nav(sol["R"][i], sol["p"][i])
        T = Ta.compose(gtsam.Pose3.Expmap(w * gtsam.Pose3.Logmap(Ta.between(Tb))))
        out["R"][k], out["p"][k] = T.rotation().matrix(), T.translation()
        for name in ("v", "bg", "ba"):
            out[name][k] = (1 - w) * psol[name][j] + w * sol[name][i]
