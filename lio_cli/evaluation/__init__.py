"""Trajectory evaluation: association, alignment, APE/RPE (as evo defines them), KITTI segment errors, drift.

The math lives in ``association``, ``alignment`` and ``metrics``; ``evaluate`` runs them in order for one
estimate against one reference and returns plain data (``EvalResult``). Plots are in ``plots`` (matplotlib,
imported only when asked). Nothing here prints.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from ..errors import InputError
from .alignment import MODES as ALIGN_MODES
from .alignment import Alignment, align, umeyama
from .association import METHODS as ASSOC_METHODS
from .association import Association, Trajectory, associate, explain_no_match, match_nearest
from .metrics import (
    DELTA_UNITS,
    KITTI_LENGTHS_M,
    STATISTICS,
    ape_errors,
    drift,
    kitti_segment_errors,
    rpe_errors,
    rpe_pairs,
    statistics,
)

RELATIONS = ("trans", "rot", "rot_rad", "full")
RELATION_UNITS = {"trans": "m", "rot": "deg", "rot_rad": "rad", "full": ""}
MIN_MATCHES = 3


@dataclass
class EvalOptions:
    max_diff_ns: int = 10_000_000
    offset_ns: int = 0
    method: str = "nearest"
    align: str = "se3"
    n_align: int | None = None
    delta: float = 1.0
    delta_unit: str = "frames"
    all_pairs: bool = False
    pairs_from_reference: bool = False
    delta_tol: float = 0.1
    kitti_lengths_m: tuple[float, ...] = KITTI_LENGTHS_M


@dataclass
class EvalResult:
    """Everything ``evaluate`` computed for one estimate; ``summary()`` is the JSON-able part."""

    name: str
    association: Association
    alignment: Alignment
    est_aligned: np.ndarray  # (N,4,4)
    ape: dict[str, np.ndarray]
    rpe: dict[str, np.ndarray]
    rpe_pairs: np.ndarray
    kitti: dict
    drift: dict
    options: EvalOptions
    ref_length: int = 0
    est_length: int = 0
    stats: dict = field(default_factory=dict)

    def __post_init__(self) -> None:
        self.stats = {
            "ape": {rel: statistics(self.ape[rel]) for rel in RELATIONS},
            "rpe": {rel: statistics(self.rpe[rel]) for rel in RELATIONS},
        }

    def flat_metrics(self) -> dict[str, float | int | None]:
        """Flat ``name -> value`` of every metric (the names --fail-above and --csv use)."""
        out: dict[str, float | int | None] = {"matches": len(self.association.ref)}
        for kind in ("ape", "rpe"):
            for rel in RELATIONS:
                for stat, v in self.stats[kind][rel].items():
                    out[f"{kind}_{rel}_{stat}"] = v
            out[f"{kind}_rmse"] = self.stats[kind]["trans"]["rmse"]
        out["rpe_pairs"] = len(self.rpe_pairs)
        out["kitti_trans_pct"] = self.kitti["trans_pct"]
        out["kitti_rot_deg_per_100m"] = self.kitti["rot_deg_per_100m"]
        out["kitti_segments"] = self.kitti["segments"]
        out["final_error_m"] = self.drift["final_error_m"]
        out["drift_pct"] = self.drift["drift_pct"]
        out["path_length_m"] = self.drift["path_length_m"]
        out["scale"] = self.alignment.scale
        return out

    def summary(self) -> dict:
        a = self.association
        o = self.options
        return {
            "estimate": self.name,
            "reference": a.ref.name,
            "poses": {"reference": self.ref_length, "estimate": self.est_length, "matched": len(a.ref)},
            "association": {"method": a.method, "t_max_diff_s": o.max_diff_ns / 1e9, "t_offset_s": o.offset_ns / 1e9,
                            "interpolated": a.interpolated},
            "alignment": {"mode": self.alignment.mode, "poses_used": self.alignment.n_used,
                          "scale": self.alignment.scale, "sim3": self.alignment.matrix},
            "ape": {rel: {"unit": RELATION_UNITS[rel], **self.stats["ape"][rel]} for rel in RELATIONS},
            "rpe": {"delta": o.delta, "delta_unit": o.delta_unit, "all_pairs": o.all_pairs, "pairs": len(self.rpe_pairs),
                    **{rel: {"unit": RELATION_UNITS[rel], **self.stats["rpe"][rel]} for rel in RELATIONS}},
            "kitti": self.kitti,
            "drift": self.drift,
        }


def evaluate(ref: Trajectory, est: Trajectory, options: EvalOptions | None = None) -> EvalResult:
    """Associate, align, and compute APE, RPE, KITTI segment errors and drift of ``est`` against ``ref``."""
    o = options or EvalOptions()
    assoc = associate(ref, est, o.max_diff_ns, o.offset_ns, o.method)
    n = len(assoc.ref)
    need = MIN_MATCHES if o.align in ("se3", "sim3", "scale") else 2
    if n < need:
        raise InputError(
            f"only {n} matching pose{'s' if n != 1 else ''} between {ref.name} and {est.name} "
            f"(need at least {need}); check --t-max-diff and --t-offset"
        )
    al = align(assoc.ref.poses, assoc.est.poses, o.align, o.n_align)
    est_al = al.apply(assoc.est.poses) if o.align != "none" else assoc.est.poses
    ref_p = assoc.ref.poses
    ape = ape_errors(ref_p, est_al)
    src = ref_p if o.pairs_from_reference else est_al
    src_stamps = assoc.ref.stamps_ns if o.pairs_from_reference else assoc.est.stamps_ns
    pairs = rpe_pairs(src, src_stamps, o.delta, o.delta_unit, o.all_pairs, o.delta_tol)
    rpe = rpe_errors(ref_p, est_al, pairs)
    kitti = kitti_segment_errors(ref_p, est_al, o.kitti_lengths_m)
    return EvalResult(est.name, assoc, al, est_al, ape, rpe, pairs, kitti, drift(ref_p, est_al), o,
                      ref_length=len(ref), est_length=len(est))


__all__ = [
    "ALIGN_MODES", "ASSOC_METHODS", "DELTA_UNITS", "RELATIONS", "STATISTICS", "Alignment", "Association",
    "EvalOptions", "EvalResult", "Trajectory", "align", "ape_errors", "associate", "evaluate", "explain_no_match",
    "kitti_segment_errors", "match_nearest", "rpe_errors", "rpe_pairs", "statistics", "umeyama", "drift",
]
