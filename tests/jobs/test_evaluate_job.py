"""The evaluate job: a picklable description whose run gives the numbers the CLI prints, without printing."""

from __future__ import annotations

import json
import pickle

import numpy as np
import pytest

from lio_cli.cli.app import main
from lio_cli.errors import InputError
from lio_cli.evaluation import EvalOptions
from lio_cli.evaluation.groups import Group
from lio_cli.jobs.evaluate import EvaluateJob, run_evaluate


def _write_tum(path, stamps_s, xyz):
    lines = [f"{t:.9f} {p[0]:.9f} {p[1]:.9f} {p[2]:.9f} 0 0 0 1" for t, p in zip(stamps_s, xyz)]
    path.write_text("\n".join(lines) + "\n")


@pytest.fixture
def tums(tmp_path):
    t = 100.0 + np.arange(50) * 0.1
    xyz = np.c_[np.cos(t), np.sin(t), 0.1 * t]
    gt, a, b = tmp_path / "gt.tum", tmp_path / "a.tum", tmp_path / "b.tum"
    _write_tum(gt, t, xyz)
    _write_tum(a, t, xyz + [0.3, 0.0, 0.0])  # off by 0.3 m everywhere: APE 0.3 without alignment
    _write_tum(b, t, xyz + [0.0, 0.0, -0.1])
    return gt, a, b


def test_job_pickles_and_gives_the_known_errors_and_group_statistics(tums, tmp_path, capsys):
    gt, a, b = tums
    job = EvaluateJob(str(gt), (str(a), str(b)), EvalOptions(align="none"), groups=(Group("both", [str(a), str(b)]),))
    job = pickle.loads(pickle.dumps(job))
    res = run_evaluate(job)
    rmse = [r.flat_metrics()["ape_rmse"] for r in res.results]
    assert rmse == pytest.approx([0.3, 0.1], abs=1e-9)
    (stats,) = res.report["groups"]
    assert stats["metrics"]["ape_rmse"]["mean"] == pytest.approx(0.2, abs=1e-9)
    assert res.notes == [] and res.warnings == []
    assert capsys.readouterr() == ("", "")  # the job prints nothing
    # the CLI is this job: same metrics in its JSON
    assert main(["evaluate", str(gt), str(a), str(b), "--align", "none", "--json", "-q"]) == 0
    cli = json.loads(capsys.readouterr().out)
    assert [m["ape_rmse"] for m in cli["metrics"]] == rmse


def test_kitti_length_mismatch_is_bad_input(tmp_path):
    gt, est = tmp_path / "gt.txt", tmp_path / "est.txt"
    row = "1 0 0 0 0 1 0 0 0 0 1 0\n"
    gt.write_text(row * 5)
    est.write_text(row * 4)
    with pytest.raises(InputError, match=r"4 KITTI poses but the ground truth .* has 5"):
        run_evaluate(EvaluateJob(str(gt), (str(est),), EvalOptions(), rate_hz=10.0))
