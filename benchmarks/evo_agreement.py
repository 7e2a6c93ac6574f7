"""Validate `lio evaluate` against evo, the reference implementation, on simulated trajectories.

Run:  python benchmarks/evo_agreement.py [--evo-venv /tmp/evo-venv] [--poses 2000] [--seed 7]

evo is installed into a scratch venv (created with `python -m venv` + `pip install evo` when missing), and is
run there through its Python API on the same TUM files; lio runs in this process. For every association,
alignment, pose relation and RPE delta below, all seven statistics (rmse mean median std min max sse) of
both tools are printed side by side with the worst relative difference. Exit code 1 if any differs by more
than 1e-9 relative (values where both are below 1e-12, i.e. zero up to rounding, count as equal).
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from lio_cli.evaluation import EvalOptions, Trajectory, evaluate  # noqa: E402
from lio_cli.geometry import so3_exp  # noqa: E402
from lio_cli.io.files.trajectory import format_tum, read_tum  # noqa: E402

REL_TOL = 1e-9
# Values below this (m, deg, rad, unitless) are zero up to float rounding in both tools (e.g. the APE minimum at
# the pose used for origin alignment: 2e-16 vs 5e-16); a relative difference means nothing there.
ABS_FLOOR = 1e-12
STATS = ("rmse", "mean", "median", "std", "min", "max", "sse")

# (label, association, alignment, n_align); evo flags in the comment
ALIGNMENTS = [
    ("none", "none", None),  # (no flag)
    ("se3", "se3", None),  # -a
    ("sim3", "sim3", None),  # -a -s
    ("scale", "scale", None),  # -s
    ("origin", "origin", None),  # --align_origin
    ("se3 first 100", "se3", 100),  # -a --n_to_align 100
    ("sim3 first 100", "sim3", 100),  # -a -s --n_to_align 100
]
RPE_DELTAS = [  # (delta, unit, all_pairs)
    (1, "frames", False),
    (10, "frames", True),
    (5.0, "m", False),
    (2.0, "m", True),
    (10.0, "deg", False),
    (0.2, "rad", False),
]
EVO_UNITS = {"frames": "frames", "m": "meters", "deg": "degrees", "rad": "radians"}
RELATIONS = [("trans", "translation_part"), ("rot", "rotation_angle_deg"), ("rot_rad", "rotation_angle_rad"),
             ("full", "full_transformation")]

EVO_SNIPPET = r"""
import json, sys
import numpy as np
from evo.core import metrics, sync
from evo.core.sync_method import SyncMethod
from evo.core.units import Unit
from evo.tools import file_interface
cfg = json.load(sys.stdin)
ref0 = file_interface.read_tum_trajectory_file(cfg["ref"])
ests = {path: file_interface.read_tum_trajectory_file(path) for path in {job["est"] for job in cfg["jobs"]}}
out = []
for job in cfg["jobs"]:
    est0 = ests[job["est"]]
    method = SyncMethod.interpolation if job["method"] == "interpolate" else SyncMethod.nearest_time
    ref, est = sync.associate_trajectories(ref0, est0, sync_method=method, max_diff=job["max_diff"],
                                           offset_2=job["offset"])
    mode, n = job["align"], job["n_align"] or -1
    if mode in ("se3", "sim3", "scale"):
        est.align(ref, correct_scale=mode == "sim3", correct_only_scale=mode == "scale", n=n)
    elif mode == "origin":
        est.align_origin(ref)
    res = {"matches": ref.num_poses}
    for name, rel in job["relations"]:
        ape = metrics.APE(metrics.PoseRelation[rel])
        ape.process_data((ref, est))
        res["ape_" + name] = ape.get_all_statistics()
        for k, (delta, unit, all_pairs) in enumerate(job["rpe"]):
            rpe = metrics.RPE(metrics.PoseRelation[rel], delta, Unit[unit], 0.1, all_pairs, job["from_ref"])
            rpe.process_data((ref, est))
            res[f"rpe{k}_" + name] = rpe.get_all_statistics()
    out.append(res)
json.dump(out, sys.stdout)
"""


def ensure_evo(venv: Path) -> Path:
    py = venv / "bin" / "python"
    if not py.exists():
        print(f"creating {venv} and installing evo (pip install evo)...", file=sys.stderr)
        subprocess.run([sys.executable, "-m", "venv", str(venv)], check=True)
    probe = subprocess.run([str(py), "-c", "import evo"], capture_output=True)
    if probe.returncode != 0:
        subprocess.run([str(py), "-m", "pip", "install", "-q", "evo"], check=True)
    return py


def simulate(n: int, seed: int, stamp0_s: float = 1000.0) -> tuple[Trajectory, Trajectory]:
    """Ground truth at 100 Hz on a 3D figure with turns; estimate at ~1/3 the rate with jitter, Sim(3) offset, drift, noise."""
    rng = np.random.default_rng(seed)
    t = np.arange(n) * 0.01
    stamps_ref = np.int64(stamp0_s * 1e9) + np.round(t * 1e9).astype(np.int64)
    pos = np.stack([20 * np.sin(0.05 * t), 12 * np.sin(0.1 * t) + 0.3 * t, 1.5 * np.sin(0.2 * t)], axis=1)
    rotvec = np.stack([0.2 * np.sin(0.3 * t), 0.15 * np.cos(0.25 * t), 0.4 * t], axis=1)
    ref = np.repeat(np.eye(4)[None], n, axis=0)
    ref[:, :3, :3] = so3_exp(rotvec)
    ref[:, :3, 3] = pos
    keep = np.arange(0, n, 3)
    m = len(keep)
    jitter_ns = rng.integers(-3_000_000, 3_000_000, m)
    stamps_est = stamps_ref[keep] + jitter_ns
    stamps_est = np.maximum.accumulate(stamps_est + np.arange(m))  # strictly increasing
    S = np.eye(4)
    S[:3, :3] = so3_exp(np.array([0.1, -0.2, 0.7]))
    S[:3, 3] = [3.0, -1.0, 0.5]
    est = S @ ref[keep]
    est[:, :3, 3] *= 1.03  # scale error
    drift = np.cumsum(rng.normal(0, 0.002, (m, 3)), axis=0)
    est[:, :3, 3] += drift + rng.normal(0, 0.01, (m, 3))
    est[:, :3, :3] = est[:, :3, :3] @ so3_exp(rng.normal(0, 0.003, (m, 3)))
    return Trajectory(stamps_ref, ref, "ref"), Trajectory(stamps_est, est, "est")


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--evo-venv", type=Path, default=Path(os.environ.get("EVO_VENV", "/tmp/evo-venv")))
    ap.add_argument("--poses", type=int, default=3000)
    ap.add_argument("--seed", type=int, default=7)
    ap.add_argument("--t0", type=float, default=1000.0,
                    help="first stamp (s); with Unix-epoch stamps (1.7e9) evo's float seconds keep only ~0.2 us, so "
                         "its interpolation weights (not lio's, which uses int ns) move by ~1e-5 relative")
    args = ap.parse_args()
    evo_py = ensure_evo(args.evo_venv)
    ref_sim, est_sim = simulate(args.poses, args.seed, args.t0)
    with tempfile.TemporaryDirectory() as tmp:
        ref_path, est_path = Path(tmp, "ref.tum"), Path(tmp, "est.tum")
        ref_path.write_text(format_tum(ref_sim.stamps_ns, ref_sim.poses))
        est_path.write_text(format_tum(est_sim.stamps_ns, est_sim.poses))
        # the same estimate on a clock 2.5 s ahead, paired back with --t-offset -2.5
        shifted_path = Path(tmp, "est_shifted.tum")
        shifted_path.write_text(format_tum(est_sim.stamps_ns + 2_500_000_000, est_sim.poses))
        jobs = []

        def make_job(label, method, mode, n_align, est=est_path, offset=0.0, from_ref=False, max_diff=0.01):
            return {"label": label, "method": method, "align": mode, "n_align": n_align, "max_diff": max_diff,
                    "offset": offset, "est": str(est), "from_ref": from_ref,
                    "relations": [(a, b) for a, b in RELATIONS],
                    "rpe": [(d, EVO_UNITS[u], ap_) for d, u, ap_ in RPE_DELTAS]}

        for method in ("nearest", "interpolate"):
            for label, mode, n_align in ALIGNMENTS:
                jobs.append(make_job(label, method, mode, n_align))
            jobs.append(make_job("se3 offset -2.5s", method, "se3", None, est=shifted_path, offset=-2.5))
        jobs.append(make_job("se3 pairs on ref", "nearest", "se3", None, from_ref=True))
        jobs.append(make_job("se3 max_diff 2ms", "nearest", "se3", None, max_diff=0.002))
        cfg = {"ref": str(ref_path), "est": str(est_path), "jobs": jobs}
        proc = subprocess.run([str(evo_py), "-c", EVO_SNIPPET], input=json.dumps(cfg), capture_output=True, text=True)
        if proc.returncode != 0:
            print(proc.stderr, file=sys.stderr)
            return 2
        evo_out = json.loads(proc.stdout)
        rs, rp = read_tum(ref_path)
        ref = Trajectory(rs, rp, "ref")
        loaded = {}
        for path in {j["est"] for j in jobs}:
            es, ep = read_tum(path)
            loaded[path] = Trajectory(es, ep, "est")
        worst_all = 0.0
        print(f"{'association':<12} {'alignment':<17} {'metric':<26} {'stat':<6} {'lio':>22} {'evo':>22} {'rel diff':>9}")
        summary = []
        for job, ev in zip(jobs, evo_out):
            worst_job = 0.0
            mine = {}
            for k, (delta, unit, all_pairs) in enumerate(RPE_DELTAS):
                opts = EvalOptions(method=job["method"], align=job["align"], n_align=job["n_align"], delta=delta,
                                   delta_unit=unit, all_pairs=all_pairs, max_diff_ns=round(job["max_diff"] * 1e9),
                                   offset_ns=round(job["offset"] * 1e9), pairs_from_reference=job["from_ref"])
                r = evaluate(ref, loaded[job["est"]], opts)
                for rel, _ in RELATIONS:
                    mine["ape_" + rel] = r.stats["ape"][rel]
                    mine[f"rpe{k}_" + rel] = r.stats["rpe"][rel]
                matches = len(r.association.ref)
            assert matches == ev["matches"], (matches, ev["matches"])
            for key, evo_stats in ev.items():
                if key == "matches":
                    continue
                for stat in STATS:
                    a, b = mine[key][stat], float(evo_stats[stat])
                    rel = abs(a - b) / max(abs(b), 1e-300) if a != b else 0.0
                    if abs(a - b) <= ABS_FLOOR:
                        rel = min(rel, 0.0 if max(abs(a), abs(b)) <= ABS_FLOOR else rel)
                    worst_job = max(worst_job, rel)
                    if stat == "rmse" or rel > REL_TOL:
                        name = key
                        if key.startswith("rpe"):
                            d, u, ap_ = RPE_DELTAS[int(key[3])]
                            name = f"rpe {key.split('_', 1)[1]} d={d:g}{u}{' all' if ap_ else ''}"
                        print(f"{job['method']:<12} {job['label']:<17} {name:<26} {stat:<6} {a:>22.15g} {b:>22.15g} {rel:>9.1e}")
            summary.append((job["method"], job["label"], matches, worst_job))
            worst_all = max(worst_all, worst_job)
        print("\nsummary (worst relative difference over APE/RPE x 4 relations x 7 statistics x 6 RPE deltas)")
        print(f"{'association':<12} {'alignment':<17} {'matches':>8} {'worst rel diff':>15}")
        for method, label, matches, worst in summary:
            print(f"{method:<12} {label:<17} {matches:>8} {worst:>15.2e}")
        ok = worst_all <= REL_TOL
        print(f"\n{'AGREE' if ok else 'DISAGREE'}: worst relative difference {worst_all:.2e} (limit {REL_TOL:g})")
        return 0 if ok else 1


if __name__ == "__main__":
    sys.exit(main())
