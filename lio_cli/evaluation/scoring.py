"""Scoring a run against ground truth with ``lio evaluate``'s defaults (what ``odom --gt`` reports)."""

from __future__ import annotations

from dataclasses import asdict, dataclass, replace

import numpy as np

from ..model.trajectory import Trajectory
from . import EvalOptions, evaluate
from .alignment import DegenerateAlignment, line_spread
from .metrics import path_length_m

RPE_METRES_FROM_M = 20.0  # paths at least this long get RPE over 10 m, shorter ones over 1 s
LINE_SPREAD_PER_ERROR = 10.0  # see score(): the alignment's rotation about a line to ~0.1 rad


@dataclass(frozen=True)
class Score:
    """ATE (APE translation rmse, SE(3)-aligned; from the first pose, ``alignment`` origin, when the reference's
    positions lie on a line or a point) and RPE of one trajectory against a reference."""

    reference: str
    matches: int
    ate_trans_rmse_m: float
    ate_rot_rmse_deg: float
    rpe_delta: str
    rpe_trans_rmse_m: float | None
    final_error_m: float | None
    alignment: str = "se3"
    note: str | None = None  # why a number means less than it says

    def to_dict(self) -> dict:
        return asdict(self)


def score(ref: Trajectory, est: Trajectory, options: EvalOptions | None = None) -> Score:
    """ATE and RPE of ``est`` against ``ref``; RPE over 10 m when both paths are 20 m or more, else over 1 s."""
    o = options or EvalOptions()
    try:
        ate = evaluate(ref, est, o)
    except DegenerateAlignment:
        if o.align != "se3":
            raise
        # positions on a line or a point (a platform standing still): no rotation to align by; score from the
        # first pose, as a run that finished deserves a number rather than losing its outputs
        o = replace(o, align="origin")
        ate = evaluate(ref, est, o)
    note = None
    if o.align == "se3":
        # near a line the alignment's rotation about it is set by the little the path strays from the line: about
        # ATE / (spread sqrt(n)) radians; beyond ~0.1 rad the rotation error says little
        pos = ate.association.ref.poses[: ate.alignment.n_used, :3, 3]
        spread, _ = line_spread(pos)
        if spread * np.sqrt(len(pos)) < LINE_SPREAD_PER_ERROR * ate.stats["ape"]["trans"]["rmse"]:
            note = (f"the reference's positions lie near a line (they stray {spread:.3g} m from it): the alignment "
                    "cannot fix the rotation about it, so the rotation error says little (lio evaluate --align origin "
                    "measures from the first pose)")
    # RPE pairs come from the estimate (as in evo): one that stopped short of 20 m (a track lost) gets 1 s
    length = min(ate.drift["path_length_m"] or 0.0, path_length_m(ate.association.est.poses))
    delta, unit = (10.0, "m") if length >= RPE_METRES_FROM_M else (1.0, "s")
    rpe = evaluate(ref, est, replace(o, delta=delta, delta_unit=unit))
    return Score(
        reference=ref.name,
        matches=len(ate.association.ref),
        ate_trans_rmse_m=ate.stats["ape"]["trans"]["rmse"],
        ate_rot_rmse_deg=ate.stats["ape"]["rot"]["rmse"],
        rpe_delta=f"{delta:g} {unit}",
        rpe_trans_rmse_m=rpe.stats["rpe"]["trans"]["rmse"] if len(rpe.rpe_pairs) else None,
        final_error_m=ate.drift["final_error_m"],
        alignment=o.align,
        note=note,
    )
