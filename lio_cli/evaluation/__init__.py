"""Trajectory evaluation: association, alignment, APE/RPE (as evo defines them), KITTI segment errors, drift.

The math lives in ``association``, ``alignment`` and ``metrics``; ``evaluate`` runs them in order for one
estimate against one reference and returns plain data (``EvalResult``). ``offset`` estimates a constant time
offset first when asked; ``groups`` summarises several runs. Plots are in ``plots`` (matplotlib, imported only
when asked). Nothing here prints.

Position-only trajectories (GPS) are evaluated with ``translation_only``: the reference borrows the aligned
estimate's rotations, so APE translation is unchanged, and RPE and KITTI translation errors become the
difference of the two displacements in the world frame, ``|(p_j - p_i) - (q_j - q_i)|``; every rotation
metric is undefined (None).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from ..errors import InputError
from .alignment import MODES as ALIGN_MODES
from .alignment import Alignment, align, umeyama
from .association import METHODS as ASSOC_METHODS
from .association import Association, Trajectory, associate, explain_no_match, match_nearest
from .offset import OffsetEstimate, estimate_offset
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
    translation_only: bool = False  # a position-only trajectory (GPS): no rotation metrics
    estimate_offset: bool = False  # search the time offset instead of using offset_ns
    offset_range_ns: tuple[int, int] | None = None  # its search range (default: offset.default_range_ns)


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
    offset: OffsetEstimate | None = None  # when the time offset was estimated

    def __post_init__(self) -> None:
        undefined = dict.fromkeys(STATISTICS)
        self.stats = {
            "ape": {rel: statistics(self.ape[rel]) if rel in self.ape else undefined for rel in RELATIONS},
            "rpe": {rel: statistics(self.rpe[rel]) if rel in self.rpe else undefined for rel in RELATIONS},
        }

    @property
    def offset_ns(self) -> int:
        """The offset added to the estimate's stamps: estimated, or the one given."""
        return self.offset.offset_ns if self.offset is not None else self.options.offset_ns

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
        out["t_offset_s"] = self.offset_ns / 1e9
        return out

    def summary(self) -> dict:
        a = self.association
        o = self.options
        out = {
            "estimate": self.name,
            "reference": a.ref.name,
            "poses": {"reference": self.ref_length, "estimate": self.est_length, "matched": len(a.ref)},
            "translation_only": o.translation_only,
            "association": {"method": a.method, "t_max_diff_s": o.max_diff_ns / 1e9, "t_offset_s": self.offset_ns / 1e9,
                            "interpolated": a.interpolated},
            "alignment": {"mode": self.alignment.mode, "poses_used": self.alignment.n_used,
                          "scale": self.alignment.scale, "sim3": self.alignment.matrix},
            "ape": {rel: {"unit": RELATION_UNITS[rel], **self.stats["ape"][rel]} for rel in RELATIONS},
            "rpe": {"delta": o.delta, "delta_unit": o.delta_unit, "all_pairs": o.all_pairs, "pairs": len(self.rpe_pairs),
                    **{rel: {"unit": RELATION_UNITS[rel], **self.stats["rpe"][rel]} for rel in RELATIONS}},
            "kitti": self.kitti,
            "drift": self.drift,
        }
        if self.offset is not None:
            out["time_offset"] = self.offset.summary()
        return out


def evaluate(ref: Trajectory, est: Trajectory, options: EvalOptions | None = None) -> EvalResult:
    """Associate, align, and compute APE, RPE, KITTI segment errors and drift of ``est`` against ``ref``."""
    o = options or EvalOptions()
    if o.translation_only and o.align == "origin":
        raise InputError(f"--align origin needs orientations, and {ref.name} or {est.name} has positions only "
                         f"(GPS); use se3, sim3, scale, posyaw or none")
    offset = (estimate_offset(ref, est, o.max_diff_ns, o.align, o.offset_range_ns, rotations=not o.translation_only)
              if o.estimate_offset else None)
    offset_ns = offset.offset_ns if offset is not None else o.offset_ns
    assoc = associate(ref, est, o.max_diff_ns, offset_ns, o.method)
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
    if o.translation_only:  # borrow the estimate's rotations: only displacements are compared (module doc)
        ref_p = ref_p.copy()
        ref_p[:, :3, :3] = est_al[:, :3, :3]
    ape = ape_errors(ref_p, est_al)
    src = ref_p if o.pairs_from_reference else est_al
    src_stamps = assoc.ref.stamps_ns if o.pairs_from_reference else assoc.est.stamps_ns
    pairs = rpe_pairs(src, src_stamps, o.delta, o.delta_unit, o.all_pairs, o.delta_tol)
    rpe = rpe_errors(ref_p, est_al, pairs)
    kitti = kitti_segment_errors(ref_p, est_al, o.kitti_lengths_m)
    if o.translation_only:
        ape, rpe = {"trans": ape["trans"]}, {"trans": rpe["trans"]}
        kitti = _without_rotation(kitti)
    return EvalResult(est.name, assoc, al, est_al, ape, rpe, pairs, kitti, drift(ref_p, est_al), o,
                      ref_length=len(ref), est_length=len(est), offset=offset)


def _without_rotation(kitti: dict) -> dict:
    out = dict(kitti, rot_deg_per_100m=None)
    out["per_length"] = {k: dict(v, rot_deg_per_100m=None) for k, v in kitti["per_length"].items()}
    return out


__all__ = [
    "ALIGN_MODES", "ASSOC_METHODS", "DELTA_UNITS", "RELATIONS", "STATISTICS", "Alignment", "Association",
    "EvalOptions", "EvalResult", "OffsetEstimate", "Trajectory", "align", "estimate_offset", "ape_errors", "associate", "evaluate", "explain_no_match",
    "kitti_segment_errors", "match_nearest", "rpe_errors", "rpe_pairs", "statistics", "umeyama", "drift",
]
