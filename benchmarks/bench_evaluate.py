"""Time `lio evaluate` against evo on two simulated 20 000-pose TUM trajectories (APE + RPE), and check
`--estimate-offset` on a known 0.137 s clock shift.

Run:  python benchmarks/bench_evaluate.py [--poses 20000] [--evo-venv /tmp/evo-venv] [--repeat 3]

Both tools read the same files with the same settings (nearest association within 0.01 s, SE(3) Umeyama,
RPE over 1 frame). Rows:
  lio CLI      `lio evaluate GT EST --json` as a subprocess: start-up, reading, APE, RPE (+ KITTI, drift)
  lio stages   the same work in this process, stage by stage
  lio posyaw / offset   the CLI with `--align posyaw`, and with `--estimate-offset` on the shifted estimate
  evo CLI      `evo_ape ... -a` plus `evo_rpe ... -a` as subprocesses (evo needs two runs for both metrics)
  evo API      evo's Python API in its venv: read, sync, align, APE, RPE, in one process
evo is installed into a scratch venv when missing (`python -m venv` + `pip install evo`). Best of --repeat;
lio CLI, evo API and evo CLI take turns in each round, so a busy machine slows them alike.
The APE/RPE rmse of both are printed too, as a cross-check; the target is lio CLI <= 0.5x evo. The ratios
are printed in wall time and in CPU time (user + system of the subprocesses), which a shared machine disturbs less.

Offset recovery: the estimate's stamps are moved 0.137 s early and `--estimate-offset` must find +0.137 s.
Two simulations: "clean" (a smooth 3D path sampled at random instants, 1 cm and 0.03 deg white noise, another
world frame) and "evo sim" (the trajectories above: stamp jitter of +-3 ms, a 3 % scale error, a random-walk
drift of 2 mm per pose, noise), each evaluated with --align sim3.
"""

from __future__ import annotations

import argparse
import json
import os
import resource
import subprocess
import sys
import tempfile
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from bytecode_cache import use_bytecode_cache  # noqa: E402
from evo_agreement import ensure_evo, simulate  # noqa: E402

import numpy as np  # noqa: E402

from lio_cli.evaluation import Trajectory, align, ape_errors, associate, kitti_segment_errors  # noqa: E402
from lio_cli.evaluation import rpe_errors, rpe_pairs, statistics  # noqa: E402
from lio_cli.evaluation.offset import estimate_offset  # noqa: E402
from lio_cli.geometry import make_pose, so3_exp  # noqa: E402
from lio_cli.io.files.trajectory import format_tum, read_tum  # noqa: E402

SHIFT_NS = 137_000_000

EVO_API = r"""
import json, sys, time
t0 = time.perf_counter()
from evo.core import metrics, sync
from evo.tools import file_interface
ref = file_interface.read_tum_trajectory_file(sys.argv[1])
est = file_interface.read_tum_trajectory_file(sys.argv[2])
t1 = time.perf_counter()
ref, est = sync.associate_trajectories(ref, est, max_diff=0.01)
est.align(ref)
t2 = time.perf_counter()
ape = metrics.APE(metrics.PoseRelation.translation_part); ape.process_data((ref, est))
t3 = time.perf_counter()
rpe = metrics.RPE(metrics.PoseRelation.translation_part, 1, metrics.Unit.frames); rpe.process_data((ref, est))
t4 = time.perf_counter()
print(json.dumps({"read": t1 - t0, "sync_align": t2 - t1, "ape": t3 - t2, "rpe": t4 - t3, "total": t4 - t0,
                  "ape_rmse": ape.get_statistic(metrics.StatisticsType.rmse),
                  "rpe_rmse": rpe.get_statistic(metrics.StatisticsType.rmse)}))
"""


def children_cpu() -> float:
    """User + system CPU seconds of every finished child process so far."""
    ru = resource.getrusage(resource.RUSAGE_CHILDREN)
    return ru.ru_utime + ru.ru_stime


def best_of(repeat: int, fn):
    best, out = float("inf"), None
    for _ in range(repeat):
        t0 = time.perf_counter()
        out = fn()
        best = min(best, time.perf_counter() - t0)
    return best, out


def clean_pair(n: int, seed: int = 11) -> tuple[Trajectory, Trajectory]:
    """A 100 Hz reference on a smooth 3D path; ``n`` estimate poses at random instants, in another world frame,
    with white noise, stamped on a clock that reads SHIFT_NS early."""
    rng = np.random.default_rng(seed)
    duration = n / 30.0

    def motion(t):
        P = np.repeat(np.eye(4)[None], len(t), axis=0)
        P[:, :3, :3] = so3_exp(np.stack([0.2 * np.sin(0.3 * t), 0.15 * np.cos(0.25 * t), 0.4 * t], axis=1))
        P[:, :3, 3] = np.stack([20 * np.sin(0.05 * t), 12 * np.sin(0.1 * t) + 0.3 * t, 1.5 * np.sin(0.2 * t)], axis=1)
        return P

    t_ref = np.arange(0.0, duration, 0.01)
    t_est = np.sort(rng.uniform(0.5, duration - 0.5, n))
    est = make_pose(so3_exp(np.array([0.1, -0.2, 0.7])), np.array([3.0, -1.0, 0.5])) @ motion(t_est)
    est[:, :3, 3] += rng.normal(0, 0.01, (n, 3))
    est[:, :3, :3] = est[:, :3, :3] @ so3_exp(rng.normal(0, np.deg2rad(0.03), (n, 3)))
    t0 = 1_000 * 10**9
    return (Trajectory(t0 + np.round(t_ref * 1e9).astype(np.int64), motion(t_ref), "ref"),
            Trajectory(t0 + np.round(t_est * 1e9).astype(np.int64) - SHIFT_NS, est, "est"))


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--poses", type=int, default=20_000)
    ap.add_argument("--evo-venv", type=Path, default=Path(os.environ.get("EVO_VENV", "/tmp/evo-venv")))
    ap.add_argument("--repeat", type=int, default=3)
    ap.add_argument("--offset-seeds", type=int, default=5, help="seeds of the in-process offset table")
    ap.add_argument("--skip-evo-cli", action="store_true", help="skip the evo_ape/evo_rpe subprocess rows")
    args = ap.parse_args()
    use_bytecode_cache()
    evo_py = ensure_evo(args.evo_venv)
    ref_sim, est_sim = evo_pair(args.poses, 3, shift_ns=0)
    # the CLI of this checkout, exactly as the `lio` console script runs it
    repo = Path(__file__).resolve().parents[1]
    lio = [sys.executable, "-c", "import sys; from lio_cli.cli.app import main; sys.exit(main(sys.argv[1:]))"]
    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        gt, est = Path(tmp, "gt.tum"), Path(tmp, "est.tum")
        gt.write_text(format_tum(ref_sim.stamps_ns, ref_sim.poses))
        est.write_text(format_tum(est_sim.stamps_ns, est_sim.poses))

        def lio_cli():
            p = subprocess.run([*lio, "evaluate", str(gt), str(est), "--json", "--quiet"], capture_output=True,
                               text=True, check=True, cwd=repo)
            return json.loads(p.stdout)

        def evo_api():
            p = subprocess.run([str(evo_py), "-c", EVO_API, str(gt), str(est)], capture_output=True, text=True, check=True)
            return json.loads(p.stdout)

        bin_dir = Path(evo_py).parent

        def evo_cli():
            for tool in ("evo_ape", "evo_rpe"):
                subprocess.run([str(bin_dir / tool), "tum", str(gt), str(est), "-a", "--no_warnings"],
                               capture_output=True, check=True)

        # the three contenders take turns in every round, so a busy machine slows them alike
        contenders = {"lio": lio_cli, "evo_api": evo_api, **({} if args.skip_evo_cli else {"evo_cli": evo_cli})}
        best = {k: (float("inf"), None) for k in contenders}
        cpu = {k: float("inf") for k in contenders}  # user + system seconds of the subprocesses (a shared machine)
        for _ in range(args.repeat):
            for k, fn in contenders.items():
                t0, c0 = time.perf_counter(), children_cpu()
                out = fn()
                dt = time.perf_counter() - t0
                cpu[k] = min(cpu[k], children_cpu() - c0)
                if dt < best[k][0]:
                    best[k] = (dt, out)
        t_cli, rep = best["lio"]
        t_evo_proc, ev = best["evo_api"]
        t_evo_cli = best["evo_cli"][0] if "evo_cli" in best else None
        m = rep["metrics"][0]
        rows.append(("lio CLI (APE+RPE+KITTI+drift)", t_cli, m["ape_trans_rmse"], m["rpe_trans_rmse"]))

        def lio_cli_with(*extra, ref_path=gt, est_path=est):
            p = subprocess.run([*lio, "evaluate", str(ref_path), str(est_path), "--json", "--quiet", *extra],
                               capture_output=True, text=True, check=True, cwd=repo)
            return json.loads(p.stdout)

        t_py, rep_py = best_of(args.repeat, lambda: lio_cli_with("--align", "posyaw"))
        m = rep_py["metrics"][0]
        rows.append(("lio CLI --align posyaw", t_py, m["ape_trans_rmse"], m["rpe_trans_rmse"]))
        offsets = []
        for label, (r_sim, e_sim) in (("clean", clean_pair(args.poses)),
                                      ("evo sim", evo_pair(args.poses, 3))):
            r_path, e_path = Path(tmp, f"ref_{len(offsets)}.tum"), Path(tmp, f"shifted_{len(offsets)}.tum")
            r_path.write_text(format_tum(r_sim.stamps_ns, r_sim.poses))
            e_path.write_text(format_tum(e_sim.stamps_ns, e_sim.poses))
            t_off, rep_off = best_of(args.repeat, lambda: lio_cli_with("--estimate-offset", "--align", "sim3",
                                                                       ref_path=r_path, est_path=e_path))
            e = rep_off["estimates"][0]
            m = rep_off["metrics"][0]
            rows.append((f"lio CLI --estimate-offset ({label})", t_off, m["ape_trans_rmse"], m["rpe_trans_rmse"]))
            offsets.append((label, e["time_offset"]))

        stages = {}

        def lio_stages():
            t = time.perf_counter()
            rs, rp = read_tum(gt)
            es, ep = read_tum(est)
            stages["read"] = time.perf_counter() - t
            t = time.perf_counter()
            a = associate(Trajectory(rs, rp, "gt"), Trajectory(es, ep, "est"), 10_000_000)
            al = align(a.ref.poses, a.est.poses, "se3")
            est_al = al.apply(a.est.poses)
            stages["associate+align"] = time.perf_counter() - t
            t = time.perf_counter()
            ape = statistics(ape_errors(a.ref.poses, est_al)["trans"])
            stages["APE (4 relations)"] = time.perf_counter() - t
            t = time.perf_counter()
            pairs = rpe_pairs(est_al, a.est.stamps_ns, 1, "frames")
            rpe = statistics(rpe_errors(a.ref.poses, est_al, pairs)["trans"])
            stages["RPE (4 relations)"] = time.perf_counter() - t
            t = time.perf_counter()
            kitti_segment_errors(a.ref.poses, est_al)
            stages["KITTI segments"] = time.perf_counter() - t
            return ape["rmse"], rpe["rmse"]

        t_in, (ape_rmse, rpe_rmse) = best_of(args.repeat, lio_stages)
        rows.append(("lio in-process total", t_in, ape_rmse, rpe_rmse))
        for k, v in stages.items():
            rows.append((f"  lio {k}", v, None, None))

        rows.append(("evo API in-process total", ev["total"], ev["ape_rmse"], ev["rpe_rmse"]))
        for k in ("read", "sync_align", "ape", "rpe"):
            rows.append((f"  evo {k}", ev[k], None, None))
        rows.append(("evo API as a subprocess", t_evo_proc, None, None))
        if t_evo_cli is not None:
            rows.append(("evo CLI (evo_ape -a + evo_rpe -a)", t_evo_cli, None, None))
    print(f"{args.poses} poses each, {rep['estimates'][0]['poses']['matched']} pairs; best of {args.repeat}")
    print(f"{'what':<36} {'time s':>9} {'APE rmse m':>20} {'RPE rmse m':>20}")
    for name, t, a, r in rows:
        a_txt = f"{a:.15g}" if a is not None else ""
        r_txt = f"{r:.15g}" if r is not None else ""
        print(f"{name:<36} {t:>9.3f} {a_txt:>20} {r_txt:>20}")
    print(f"\nlio CLI / evo API as a subprocess: {t_cli / t_evo_proc:.2f} wall, "
          f"{cpu['lio'] / cpu['evo_api']:.2f} CPU (target <= 0.5)")
    if t_evo_cli is not None:
        print(f"lio CLI / evo CLI (evo_ape + evo_rpe): {t_cli / t_evo_cli:.2f} wall, "
              f"{cpu['lio'] / cpu['evo_cli']:.2f} CPU (target <= 0.5)")
    print("CPU s (user + system, best of the rounds): " + ", ".join(f"{k} {v:.3f}" for k, v in cpu.items()))
    print(f"\n--estimate-offset on an estimate whose clock reads {SHIFT_NS / 1e6:g} ms early:")
    print(f"{'simulation':<10} {'found s':>12} {'error ms':>9} {'+- ms':>7} {'decided by':>11} {'pos s':>12} {'rot s':>12}")
    for label, f in offsets:
        by = f["by_term"]
        pm = "flat" if f["precision_s"] is None else f"{f['precision_s'] * 1e3:.3f}"
        print(f"{label:<10} {f['offset_s']:>12.6f} {(f['offset_s'] - SHIFT_NS / 1e9) * 1e3:>9.3f} "
              f"{pm:>7} {f['decided_by']:>11} "
              f"{by['positions']['offset_s']:>12.6f} {by.get('rotations', {}).get('offset_s', float('nan')):>12.6f}")
    print(f"\nThe same in-process over seeds {args.offset_seeds}: the error against the reported 1-sigma "
          "(a precision that holds keeps |error| / sigma mostly below 2)")
    print(f"{'simulation':<10} {'seed':>4} {'error ms':>9} {'+- ms':>7} {'|err|/sigma':>11} {'decided by':>11}")
    for seed in range(args.offset_seeds):
        for label, (r_sim, e_sim) in (("clean", clean_pair(args.poses, seed)), ("evo sim", evo_pair(args.poses, seed))):
            f = estimate_offset(r_sim, e_sim, 10_000_000, "sim3")
            err = (f.offset_ns - SHIFT_NS) / 1e6
            sig = "flat" if f.precision_s is None else f"{f.precision_s * 1e3:.3f}"
            z = "" if f.precision_s is None else f"{abs(err) / (f.precision_s * 1e3):.2f}"
            print(f"{label:<10} {seed:>4} {err:>9.3f} {sig:>7} {z:>11} {f.decided_by:>11}")
    return 0


def evo_pair(poses: int, seed: int, shift_ns: int = SHIFT_NS) -> tuple[Trajectory, Trajectory]:
    """evo_agreement's simulation with ``poses`` poses each (the estimate is simulated 3x sparser, so 3x the
    ground truth is simulated and every third kept), the estimate's clock ``shift_ns`` early."""
    ref, est = simulate(3 * poses, seed=seed)
    return (Trajectory(ref.stamps_ns[::3][:poses], ref.poses[::3][:poses], "ref"),
            Trajectory(est.stamps_ns[:poses] - shift_ns, est.poses[:poses], "est"))


if __name__ == "__main__":
    sys.exit(main())
