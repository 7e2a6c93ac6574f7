"""``lio evaluate`` end to end through ``main([...])``: outputs, exit codes and the exact error lines."""

from __future__ import annotations

import csv
import io
import json
import math
from pathlib import Path

import numpy as np
import pytest

from lio_cli.cli.app import main
from lio_cli.geometry import make_pose, so3_exp
from lio_cli.io.files.trajectory import format_kitti, format_tum
from lio_cli.io.logs.writer import LogWriter

EXACT = 1e-9  # values go through 9-decimal files
S = 1_000_000_000


def _rz(deg: float) -> np.ndarray:
    return so3_exp(np.array([0.0, 0.0, np.deg2rad(deg)]))


def _write(path: Path, stamps, poses) -> Path:
    path.write_text(format_tum(np.asarray(stamps, dtype=np.int64), np.asarray(poses)))
    return path


@pytest.fixture
def three(tmp_path: Path) -> tuple[Path, Path]:
    """The hand-checked three-pose case of test_evaluation: APE trans [0, 0.3, 0.4], RPE trans [0.3, 0.5]."""
    stamps = np.array([10, 11, 12]) * S
    ref = [make_pose(t=[0, 0, 0]), make_pose(t=[1, 0, 0]), make_pose(t=[2, 0, 0])]
    est = [make_pose(t=[0, 0, 0]), make_pose(t=[1, 0.3, 0]), make_pose(_rz(90), [2, 0, 0.4])]
    return _write(tmp_path / "gt.tum", stamps, ref), _write(tmp_path / "est.tum", stamps, est)


def _run(capsys, *args) -> tuple[int, str, str]:
    code = main(["evaluate", *map(str, args)])
    out, err = capsys.readouterr()
    return code, out, err


def test_json_gives_the_hand_computed_numbers(capsys, three):
    gt, est = three
    code, out, err = _run(capsys, gt, est, "--align", "none", "--json")
    assert code == 0, err
    r = json.loads(out)["estimates"][0]
    assert r["poses"] == {"reference": 3, "estimate": 3, "matched": 3}
    assert r["ape"]["trans"]["rmse"] == pytest.approx(math.sqrt(0.25 / 3), rel=EXACT)
    assert r["ape"]["trans"]["sse"] == pytest.approx(0.25, rel=EXACT)
    assert r["ape"]["rot"]["max"] == pytest.approx(90.0, rel=EXACT)
    assert r["ape"]["full"]["max"] == pytest.approx(math.sqrt(4.16), rel=EXACT)
    assert r["rpe"]["trans"]["mean"] == pytest.approx(0.4, rel=EXACT)
    assert r["rpe"]["rot"]["median"] == pytest.approx(45.0, rel=EXACT)
    assert r["drift"]["final_error_m"] == pytest.approx(0.4, rel=EXACT)
    assert "APE translation" in err  # the table moves to stderr when stdout carries JSON
    assert json.loads(out)["options"]["align"] == "none"


def test_an_estimate_from_standard_input(capsys, three, monkeypatch):
    """`lio odom LOG -o - | lio evaluate GT -`: once "-: no such file or folder"."""
    gt, est = three
    monkeypatch.setattr("sys.stdin", io.StringIO(est.read_text()))
    code, out, err = _run(capsys, gt, "-", "--align", "none", "--json")
    assert code == 0, err
    assert json.loads(out)["estimates"][0]["ape"]["trans"]["rmse"] == pytest.approx(math.sqrt(0.25 / 3), rel=EXACT)
    monkeypatch.setattr("sys.stdin", io.StringIO(""))
    code, _, err = _run(capsys, gt, "-")
    assert code == 2 and err.strip() == "lio: error: -: no poses in file"


def test_table_and_csv(capsys, three, tmp_path):
    gt, est = three
    code, out, _ = _run(capsys, gt, est, est, "--align", "origin")
    assert code == 0
    assert "estimate" in out and "APE rmse m" in out and out.count("est.tum") >= 2  # one comparison table
    code, out, _ = _run(capsys, gt, est, "--align", "none", "--csv", "-")
    assert code == 0
    rows = list(csv.DictReader(io.StringIO(out)))
    assert rows[0]["estimate"] == str(est)
    assert float(rows[0]["ape_trans_max"]) == pytest.approx(0.4, rel=EXACT)
    target = tmp_path / "r.csv"
    assert _run(capsys, gt, est, "--align", "none", "--csv", target)[0] == 0
    assert target.read_text().startswith("estimate,matches,")
    code, _, err = _run(capsys, gt, est, "--align", "none", "--csv", target)
    assert code == 2 and err.strip() == f"lio: error: {target}: already exists; pass --force to overwrite it"


def test_fail_above_exits_1_naming_metric_value_limit(capsys, three):
    gt, est = three
    code, _, err = _run(capsys, gt, est, "--align", "none", "--fail-above", "ape_rmse=0.1", "--fail-above", "rpe_trans_max=1")
    assert code == 1
    assert err.strip().splitlines()[-1] == f"lio: error: --fail-above: {est}: ape_rmse = 0.288675 exceeds 0.1"
    assert _run(capsys, gt, est, "--align", "none", "--fail-above", "ape_rmse=0.5")[0] == 0
    code, _, err = _run(capsys, gt, est, "--fail-above", "ape_rsme=0.5")
    assert code == 2 and "unknown metric ape_rsme" in err
    code, _, err = _run(capsys, gt, est, "--fail-above", "ape_rmse")
    assert code == 2 and "is not METRIC=VALUE" in err


def _bad(tmp_path: Path, text: str) -> Path:
    p = tmp_path / "bad.tum"
    p.write_text(text)
    return p


@pytest.mark.parametrize(
    ("text", "message"),
    [
        ("10 0 0 0 0 0 0 1\n11 0 0 0 0 0 1\n", "bad.tum:2: expected 8 values (stamp tx ty tz qx qy qz qw), found 7"),
        ("10 0 0 0 0 0 0 1\n9 0 0 0 0 0 0 1\n", "bad.tum:2: timestamp 9 goes backwards from the previous line's (10); stamps must increase strictly"),
        ("10 0 0 0 0 0 0 1\n11 nan 0 0 0 0 0 1\n", "bad.tum:2: NaN or infinite value"),
        ("10 0 0 0 0 0 0 1\n11 0 0 0 0.5 0 0 1\n", "bad.tum:2: quaternion is not unit length (norm 1.118034)"),
    ],
)
def test_bad_estimate_lines_exit_2(capsys, three, tmp_path, text, message):
    gt, _ = three
    code, out, err = _run(capsys, gt, _bad(tmp_path, text))
    assert code == 2 and out == ""
    assert err.strip() == f"lio: error: {tmp_path}/{message}"


def test_too_few_and_no_matches_exit_2(capsys, three, tmp_path):
    gt, _ = three
    two = _write(tmp_path / "two.tum", [10 * S, 11 * S], [np.eye(4), np.eye(4)])
    code, _, err = _run(capsys, gt, two)
    assert code == 2
    assert err.strip() == f"lio: error: only 2 matching poses between {gt} and {two} (need at least 3); check --t-max-diff and --t-offset"
    ms = _write(tmp_path / "ms.tum", np.array([10_000, 11_000, 12_000]) * S, [np.eye(4)] * 3)  # milliseconds written as seconds
    code, _, err = _run(capsys, gt, ms)
    assert code == 2
    assert err.strip() == (
        f"lio: error: no matching timestamps between {gt} (10.000000..12.000000 s) and {ms} "
        f"(10000.000000..12000.000000 s) within --t-max-diff 0.01 s (offset 0 s): {ms}'s stamps look like ms "
        f"read as seconds; pass --est-stamp-unit ms"
    )
    code, out, _ = _run(capsys, gt, ms, "--est-stamp-unit", "ms", "--align", "none", "--json")
    assert code == 0 and json.loads(out)["estimates"][0]["poses"]["matched"] == 3


def test_offset_and_interpolation(capsys, three, tmp_path):
    gt, _ = three
    late = _write(tmp_path / "late.tum", np.array([110, 110.5, 111, 112]) * S,
                  [make_pose(t=[0, 0, 0]), make_pose(t=[0.5, 0, 0]), make_pose(t=[1, 0, 0]), make_pose(t=[2, 0, 0])])
    code, _, err = _run(capsys, gt, late)
    assert code == 2 and "the time ranges do not overlap; if the clocks differ by a constant, pass --t-offset -100" in err
    code, out, _ = _run(capsys, gt, late, "--t-offset", "-100", "--align", "none", "--interpolate", "--json")
    assert code == 0
    r = json.loads(out)["estimates"][0]
    assert r["association"]["interpolated"] == "estimate"  # the denser one is resampled, as in evo
    assert r["poses"]["matched"] == 3 and r["ape"]["trans"]["max"] == pytest.approx(0.0, abs=EXACT)


def test_kitti_inputs(capsys, tmp_path):
    poses = np.stack([make_pose(t=[float(k), 0.0, 0.0]) for k in range(5)])
    gt = tmp_path / "gt.txt"
    gt.write_text(format_kitti(poses))
    est = tmp_path / "est.txt"
    est.write_text(format_kitti(poses[:4]))
    times = tmp_path / "times.txt"
    times.write_text("".join(f"{0.1 * k:.6e}\n" for k in range(5)))
    code, _, err = _run(capsys, gt, est, "--times", times, "--align", "none")
    assert code == 2
    assert err.strip() == f"lio: error: {est}: 4 KITTI poses but {times} holds 5 stamps; lengths must match line by line"
    code, _, err = _run(capsys, gt, est, "--rate", "10", "--align", "none")
    assert code == 2
    assert err.strip() == (f"lio: error: {est}: 4 KITTI poses but the ground truth {gt} has 5; KITTI pose files "
                           f"pair line by line and must have the same length")
    code, _, err = _run(capsys, gt, est)
    assert code == 2 and "KITTI poses carry no stamps; give --times FILE (KITTI times.txt) or --rate HZ" in err
    est.write_text(format_kitti(poses))
    code, out, _ = _run(capsys, gt, est, "--times", times, "--align", "none", "--json")
    assert code == 0 and json.loads(out)["estimates"][0]["ape"]["trans"]["max"] == pytest.approx(0.0, abs=EXACT)


def test_ground_truth_from_a_log_topic(capsys, tmp_path):
    stamps = (np.arange(30) * 100_000_000 + 3 * S).astype(np.int64)
    poses = np.stack([make_pose(_rz(3.0 * k), [0.4 * k, 0.05 * k * k, 0.01 * k]) for k in range(30)])
    bag = tmp_path / "run.bag"
    with LogWriter(bag, "ros1") as w:
        w.add_topic("/ground_truth", "geometry_msgs/msg/PoseStamped")
        for s, T in zip(stamps, poses):
            w.write("/ground_truth", int(s), w.make.pose_stamped(int(s), "world", T))
    est_poses = poses.copy()
    est_poses[:, 1, 3] += 0.2  # a constant 0.2 m offset in y
    est = _write(tmp_path / "est.tum", stamps, est_poses)
    for gt_spec in (f"{bag}:/ground_truth", f"{bag}#/ground_truth", str(bag)):
        code, out, err = _run(capsys, gt_spec, est, "--align", "none", "--json")
        assert code == 0, err
        r = json.loads(out)["estimates"][0]
        assert r["poses"]["matched"] == 30
        assert r["ape"]["trans"]["rmse"] == pytest.approx(0.2, rel=EXACT)
    code, _, err = _run(capsys, bag, est, "--gt-topic", "/gt")
    assert code == 2 and err.strip() == f"lio: error: {bag}: topic /gt not found; ground-truth topics here: /ground_truth"
    code, out, _ = _run(capsys, f"{bag}:/ground_truth", est, "--json")  # se3 removes the constant offset
    assert code == 0 and json.loads(out)["estimates"][0]["ape"]["trans"]["rmse"] == pytest.approx(0.0, abs=1e-6)


def test_plots_and_metrics_json(capsys, tmp_path):
    n = 200
    t = np.linspace(0, 2 * np.pi, n)
    stamps = (np.arange(n) * 50_000_000).astype(np.int64)
    ref = np.stack([make_pose(_rz(np.rad2deg(a) + 90), [10 * np.cos(a), 10 * np.sin(a), 0.0]) for a in t])
    rng = np.random.default_rng(1)
    est = ref.copy()
    est[:, :3, 3] += rng.normal(0, 0.05, (n, 3))
    gt_p, est_p = _write(tmp_path / "gt.tum", stamps, ref), _write(tmp_path / "est.tum", stamps, est)
    plots = tmp_path / "plots"
    code, _, err = _run(capsys, gt_p, est_p, "--plot", plots, "--quiet")
    assert code == 0, err
    for name in ("top_view.png", "ape.png", "rpe_histogram.png"):
        data = (plots / name).read_bytes()
        assert data[:8] == b"\x89PNG\r\n\x1a\n" and len(data) > 10_000
    metrics = json.loads((plots / "metrics.json").read_text())
    assert metrics["estimates"][0]["poses"]["matched"] == n
    code, _, err = _run(capsys, gt_p, est_p, "--plot", plots)
    assert code == 2 and "top_view.png: already exists; pass --force to overwrite it" in err
    assert _run(capsys, gt_p, est_p, "--plot", plots, "--force", "--quiet")[0] == 0


def test_usage_errors_exit_2(capsys, three, tmp_path):
    gt, est = three
    for args, message in (
        (["--align", "umeyama"], "Invalid value for '--align': 'umeyama' is not one of 'none', 'se3', 'sim3', 'scale', "
                                 "'origin', 'posyaw'; see 'lio evaluate --help'"),
        (["--delta-unit", "parsecs"], "--delta-unit must be frames, m, s, deg or rad, got 'parsecs'"),
        (["--t-offset", "soon"], "--t-offset 'soon' is not a number of seconds"),
        (["--json", "--csv", "-"], "--json and --csv - would both write to stdout; give --csv a file name"),
        (["--n-align", "10", "--align", "origin"], "--n-align needs --align se3, sim3, scale or posyaw (not origin)"),
        (["--delta", "5", "--align", "none"], "RPE with --delta 5 frames found no pose pairs among 3 poses; lower --delta"),
        ([], "the trajectory is degenerate for Umeyama alignment (positions on a line or a point); "
             "use --align origin or --align none"),
    ):
        code, _, err = _run(capsys, gt, est, *args)
        assert code == 2 and err.strip() == f"lio: error: {message}", args
    code, _, err = _run(capsys, gt, "missing.tum", "--plot", tmp_path / "plots")
    assert code == 2 and err.strip() == "lio: error: missing.tum: no such file or folder"
    assert not (tmp_path / "plots").exists()  # nothing is left behind by a failed run


@pytest.mark.parametrize("csv_name, message", [
    ("p/metrics.json", "p/metrics.json: would be both the CSV file (--csv) and the file metrics.json of --plot p"),
    ("p/ape.png", "p/ape.png: would be both the CSV file (--csv) and the file ape.png of --plot p"),
    ("p", "p: would be both the CSV file (--csv) and the plot folder (--plot)"),
])
def test_csv_and_plot_sharing_a_path_are_refused_before_anything_is_written(capsys, three, tmp_path, monkeypatch,
                                                                           csv_name, message):
    gt, est = three
    monkeypatch.chdir(tmp_path)
    (tmp_path / "p").mkdir()
    before = sorted(p.name for p in tmp_path.rglob("*"))
    code, out, err = _run(capsys, gt, est, "--csv", csv_name, "--plot", "p", "--force")
    assert code == 2 and out == ""
    assert err.strip() == f"lio: error: {message}; give each output its own path"
    assert sorted(p.name for p in tmp_path.rglob("*")) == before


def test_plot_dash_is_no_stdout(capsys, three, tmp_path, monkeypatch):
    gt, est = three
    monkeypatch.chdir(tmp_path)
    before = sorted(p.name for p in tmp_path.rglob("*"))
    code, _, err = _run(capsys, gt, est, "--plot", "-")
    assert code == 2
    assert err.strip() == ("lio: error: --plot writes PNG files and metrics.json into a folder, not standard output: "
                           "give --plot a path")
    assert sorted(p.name for p in tmp_path.rglob("*")) == before


def test_se3_on_a_nearly_straight_reference_warns_that_its_roll_is_a_guess(capsys, tmp_path):
    """A straight drive: Umeyama turns the estimate about the line to absorb its small vertical error, and the
    APE rotation then reports 0.74 deg that the estimate (rotations exact) does not have."""
    x = np.arange(0, 40.0, 0.1)
    stamps = np.arange(len(x)) * (S // 10)
    ref = [make_pose(t=[v, 0.1 * np.sin(v), 0.0]) for v in x]
    est = [make_pose(t=[v, 0.1 * np.sin(v), 0.03 * np.sin(0.5 * v)]) for v in x]
    gt, es = _write(tmp_path / "gt.tum", stamps, ref), _write(tmp_path / "est.tum", stamps, est)
    code, out, err = _run(capsys, gt, es, "--json")
    assert code == 0
    assert json.loads(out)["estimates"][0]["ape"]["rot"]["rmse"] == pytest.approx(0.7407, abs=1e-4)
    assert [line for line in err.splitlines() if "warning" in line] == [
        f"lio: warning: {es}: --align se3: the reference positions it fits lie nearly on a line (0.071 m across it "
        "against 11.5 m along, std): the rotation about that line is barely determined and can add rotation error "
        "the estimate does not have (APE rotation 0.741 deg here); --align posyaw fits the yaw only"]
    code, out, err = _run(capsys, gt, es, "--json", "--align", "posyaw")
    assert code == 0 and "warning" not in err and json.loads(out)["estimates"][0]["ape"]["rot"]["rmse"] == 0.0
    # a curve fixes every rotation: no warning
    ref = [make_pose(t=[10 * np.cos(v / 10), 10 * np.sin(v / 10), 0.0]) for v in x]
    gt = _write(tmp_path / "gt.tum", stamps, ref)
    code, out, err = _run(capsys, gt, gt, "--json")
    assert code == 0 and "warning" not in err
