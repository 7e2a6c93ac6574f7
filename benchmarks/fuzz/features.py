"""Trials aimed at the features of issues 31-36: ``lio plot`` on hostile trajectory files, ``odom --map --plot
--viz-save`` and ``deskew --map`` on mutated logs (with hostile ``--map-voxel`` and paths), ``calibrate``'s partial
results, ``fuse`` (EKF, planar, complementary, ``--smooth``) on logs with mutated NavSatFix messages, and
``lio config``. Each returns what ``runner.run_trial`` does, so the summary treats every run alike.
"""

from __future__ import annotations

import re
import shutil
from pathlib import Path

import numpy as np

import logs
import mutations as fm
from runner import BASES, classify, listing, run_lio, run_trial, tree_hash

TARGETS = {"log": 0.4, "plot": 0.17, "map": 0.17, "calibrate": 0.1, "gps": 0.13, "config": 0.03}


def run_any_trial(trial: int, args, bases: dict[str, Path]) -> dict:
    """Trial ``trial``: a mutated log through info/odom/evaluate (``runner.run_trial``) or a feature target."""
    names = [t for t in TARGETS if t in args.targets]
    p = np.array([TARGETS[t] for t in names])
    target = names[int(np.random.default_rng([args.seed, trial, 35]).choice(len(names), p=p / p.sum()))]
    if target == "log":
        return run_trial(trial, args, bases)
    return run_feature_trial(trial, target, args, bases)


def gt_file(log: Path) -> Path:
    return log.with_name(log.name.split(".")[0] + ".gt.tum")


# ---------------------------------------------------------------- trajectory files

def mutate_trajectory(src: Path, dest: Path, rng: np.random.Generator) -> tuple[Path, list[str], str]:
    """A hostile copy of a TUM file in ``dest``: (path, the options reading it needs, description)."""
    rows = [ln.split() for ln in src.read_text().splitlines() if ln.strip() and not ln.startswith("#")]
    what = str(rng.choice(["NaN", "inf", "1e300", "stamps backwards", "duplicate stamp", "one pose", "two poses",
                           "empty", "only a comment", "quaternion 0", "garbage line", "7 columns", "all one stamp",
                           "kitti", "kitti NaN", "kitti times short", "binary", "stamp 1e300", "huge file lines"]))
    k = int(rng.integers(len(rows)))
    opts: list[str] = []
    if what in ("NaN", "inf", "1e300"):
        rows[k][1 + int(rng.integers(7))] = {"NaN": "nan", "inf": "inf", "1e300": "1e300"}[what]
    elif what == "stamp 1e300":
        rows[k][0] = "1e300"
    elif what == "stamps backwards":
        rows[k][0], rows[-1 - k][0] = rows[-1 - k][0], rows[k][0]
    elif what == "duplicate stamp":
        rows.insert(k, list(rows[k]))
    elif what == "one pose":
        rows = rows[k:k + 1]
    elif what == "two poses":
        rows = rows[k:k + 2]
    elif what in ("empty", "only a comment"):
        rows = []
    elif what == "quaternion 0":
        rows[k][4:8] = ["0", "0", "0", "0"]
    elif what == "garbage line":
        rows.insert(k, ["not", "a", "pose"])
    elif what == "7 columns":
        rows[k] = rows[k][:7]
    elif what == "all one stamp":
        rows = [[rows[0][0], *r[1:]] for r in rows]
    elif what == "huge file lines":
        rows[k] = rows[k] + ["0"] * 5000
    path = dest / f"traj_{what.replace(' ', '_')}.txt"
    if what == "binary":
        path.write_bytes(bytes(rng.integers(0, 256, 4096, dtype=np.uint8)))
    elif what.startswith("kitti"):
        kitti = []
        for r in rows:
            x, y, z, qx, qy, qz, qw = map(float, r[1:8])
            n = np.sqrt(qx * qx + qy * qy + qz * qz + qw * qw)
            qx, qy, qz, qw = qx / n, qy / n, qz / n, qw / n
            rot = np.array([[1 - 2 * (qy * qy + qz * qz), 2 * (qx * qy - qz * qw), 2 * (qx * qz + qy * qw)],
                            [2 * (qx * qy + qz * qw), 1 - 2 * (qx * qx + qz * qz), 2 * (qy * qz - qx * qw)],
                            [2 * (qx * qz - qy * qw), 2 * (qy * qz + qx * qw), 1 - 2 * (qx * qx + qy * qy)]])
            kitti.append(np.hstack([rot, [[x], [y], [z]]]).ravel())
        kitti = np.array(kitti)
        if what == "kitti NaN":
            kitti[k, int(rng.integers(12))] = np.nan
        path = dest / "traj.kitti"
        np.savetxt(path, kitti, fmt="%.9g")
        if what == "kitti times short":
            (dest / "times.txt").write_text("".join(f"{float(r[0]):.9f}\n" for r in rows[: len(rows) // 2]))
            opts = ["--times", str(dest / "times.txt")]
        else:
            opts = ["--rate", str(rng.choice(["10", "0", "-5", "nan", "1e300"]))]
    else:
        text = "# comment\n" if what == "only a comment" else ""
        path.write_text(text + "".join(" ".join(r) + "\n" for r in rows))
    return path, opts, f"trajectory: {what}" + (f" (row {k})" if what in ("NaN", "inf", "1e300") else "")


# ---------------------------------------------------------------- the trial

def _mutated_log(name: str, bases: dict, dest: Path, rng: np.random.Generator, cache: dict,
                 force: str | None = None) -> tuple[Path, str]:
    src, fmt = bases[name], next(b[2] for b in BASES if b[0] == name)
    path = dest / src.name
    if force is None and rng.random() < 0.15:
        (shutil.copytree if src.is_dir() else shutil.copy2)(src, path)
        return path, "unmutated"
    if name not in cache:
        cache[name] = logs.decode_log(src, fmt)
    case = fm.Case(*cache[name], rng)
    parts = [fm.FIELD_MUTATIONS[force][0](case)] if force else []
    for _ in range(int(rng.choice([0, 1, 2], p=[0.3, 0.5, 0.2])) if force else 1):
        parts.append(fm.FIELD_MUTATIONS[case.choice(fm.applicable(case))][0](case))
    logs.write_log(path, fmt, case.conns, case.msgs)
    shutil.copy2(gt_file(src), dest / gt_file(src).name)
    return path, "; ".join(parts)


def plan_for(target: str, rng: np.random.Generator, bases: dict, tin: Path, out: Path, cache: dict):
    """(description, input paths, [(label, argv, allowed files)]) of one trial; an allowed name ending in / lets
    everything under that folder through."""
    pick = lambda seq: seq[int(rng.integers(len(seq)))]  # noqa: E731
    if target == "config":
        cmd = pick(["odom", "deskew", "fuse", "calibrate", "plot", "", "ODOM", "odom\n"])
        argv = ["config", cmd] + (["-o", str(out / "c.yaml")] if rng.random() < 0.5 else [])
        return f"config {cmd!r}", [], [("config", argv, {"c.yaml"})]
    if target == "plot":
        name = pick([b for b in bases if not b.startswith("planar")])
        src = bases[name]
        shutil.copy2(gt_file(src), tin / gt_file(src).name)
        traj, opts, desc = mutate_trajectory(gt_file(src), tin, rng)
        others = pick([[], [str(tin / gt_file(src).name)], [f"{src}:/ground_truth"],
                       [str(tin / gt_file(src).name), f"{src}:/ground_truth"]])
        trajs = [str(traj), *others] if rng.random() < 0.5 else [*others, str(traj)]
        align = ["--align", pick(["none", "se3", "sim3", "posyaw", "origin"])] if others else []
        if align and rng.random() < 0.3:
            align += ["--t-max-diff", pick(["0", "-1", "nan", "1e300", "0.001"])]
        return desc, [src, tin], [("plot", ["plot", *trajs, *opts, *align, "-o", str(out / "p"), "-q"], {"p/"})]
    if target == "gps":
        log, desc = _mutated_log("drive_gps", bases, tin, rng, cache, force="navsatfix")
        fuse = ["fuse", str(log), "-o", str(out / "f.tum"), "-q", "--estimator",
                pick(["ekf", "ekf", "planar", "complementary"])]
        if rng.random() < 0.5:
            fuse.append("--smooth")
        if rng.random() < 0.3:
            fuse += ["--use", pick(["imu,gps", "gps", "imu,wheel,gps", "gps:position"])]
        if rng.random() < 0.3:
            fuse += ["--rate", "20", "--cov", str(out / "f.cov")]
        allowed = {"f.tum", "f.fuse.metrics.json", "f.fuse.config.yaml", "f.cov"}
        plan = [("fuse", fuse, allowed)]
        if rng.random() < 0.5:
            plan.append(("evaluate", ["evaluate", f"{log}:/gps/fix", str(out / "f.tum"), "--csv", str(out / "e.csv")],
                         {"e.csv"}))
        else:
            plan.append(("plot", ["plot", str(out / "f.tum"), f"{log}:/gps/fix", "-o", str(out / "p"), "-q"], {"p/"}))
        return desc, [log], plan
    if target == "calibrate":
        name = "drive_gps" if rng.random() < 0.6 else pick(list(bases))
        log, desc = _mutated_log(name, bases, tin, rng, cache)
        argv = ["calibrate", str(log), "-o", str(out / "c.yaml")]
        if rng.random() < 0.3:
            argv += ["--wheel-radius", pick(["0.3", "0", "-1", "nan"]), "--wheel-baseline", pick(["0.6", "1e300"])]
        if rng.random() < 0.2:
            argv += ["--still", pick(["0:1", "1:0", "0:1000", "nan:1", "-5:-1"])]
        return desc, [log], [("calibrate", argv, {"c.yaml", "c.calib.metrics.json", "c.calib.config.yaml"})]
    # map: odom --map --plot (--viz-save) or deskew --map, on a mutated log, hostile voxel sizes and paths
    name = pick([b for b in bases if b != "drive_gps"])
    log, desc = _mutated_log(name, bases, tin, rng, cache)
    ext = pick([".ply", ".pcd"] * 4 + [".xyz", ""])
    voxel = ["--map-voxel", pick(["0", "-1", "nan", "1e-6", "1e300", "0.05"])] if rng.random() < 0.3 else []
    mp = str(out / f"m{ext}") if rng.random() > 0.05 else str(log)
    desc += f"; --map m{ext} {' '.join(voxel)}".rstrip()
    if rng.random() < 0.6:
        argv = ["odom", str(log), "-o", str(out / "o.tum"), "--map", mp, *voxel, "-q"]
        if rng.random() < 0.7:
            argv += ["--plot", str(out / "p")]
        if rng.random() < 0.4:
            argv += ["--viz-save", str(out / "v.rrd")]
        allowed = {"o.tum", "o.odom.metrics.json", "o.odom.config.yaml", f"m{ext}", "m.png", "p/", "v.rrd"}
        return desc, [log], [("odom --map", argv, allowed)]
    argv = ["deskew", str(log), str(out / "d.bag"), "--map", mp, *voxel, "-q"]
    allowed = {"d.bag", "d.deskew.metrics.json", "d.deskew.config.yaml", f"m{ext}", "m.png"}
    return desc, [log], [("deskew --map", argv, allowed)]


_CACHE: dict = {}


def run_feature_trial(trial: int, target: str, args, bases: dict[str, Path]) -> dict:
    rng = np.random.default_rng([args.seed, trial, 36])
    tdir = args.out / "trials" / f"{trial:04d}"
    shutil.rmtree(tdir, ignore_errors=True)
    (tdir / "in").mkdir(parents=True)
    (tdir / "out").mkdir()
    try:
        desc, inputs, plan = plan_for(target, rng, bases, tdir / "in", tdir / "out", _CACHE)
    except Exception as err:  # noqa: BLE001 - a mutation that cannot be written is the harness's problem
        return {"trial": trial, "error": f"mutation failed: {type(err).__name__}: {err}", "runs": []}
    before = {p: tree_hash(p) for p in inputs}
    out, runs = tdir / "out", []
    for label, cmd, allowed in plan:
        seen = listing(out)
        run = run_lio(cmd, out, args.timeout, args.max_as_mb, args.pywarnings)
        new = listing(out) - seen
        folders = tuple(a for a in allowed if a.endswith("/"))
        new = {f for f in new if not (run["exit"] == 0 and (f + "/" in folders or f.startswith(folders)))}
        cats = classify(run, new, allowed, args)
        if run["exit"] == 0 and label in ("fuse", "odom --map"):
            tum = next((out / n for n in ("f.tum", "o.tum") if (out / n).exists()), None)
            if tum and re.search(r"nan|inf", tum.read_text(), re.I):
                cats.append("nan output")
        if run["exit"] == 0 and label == "calibrate" and re.search(r"\bnan\b|\binf\b", (out / "c.yaml").read_text()):
            cats.append("nan output")
        runs.append({"command": label, "argv": ["lio", *cmd], **run, "categories": cats})
        if run["exit"] != 0:
            break
    if any(tree_hash(p) != h for p, h in before.items()):
        runs[-1]["categories"].append("modified input")
    return {"trial": trial, "base": target, "mutation": desc, "input": str(inputs[0]) if inputs else "",
            "runs": runs}
