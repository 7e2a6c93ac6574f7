"""``lio evaluate`` with GPS references, posyaw, --estimate-offset and groups, end to end through ``main([...])``."""

from __future__ import annotations

import csv
import io
import json
import math
from pathlib import Path

import numpy as np
import pytest

from lio_cli.cli.app import main
from lio_cli.geodesy import EnuFrame
from lio_cli.geometry import make_pose, so3_exp
from lio_cli.io.files.trajectory import format_tum
from lio_cli.io.logs.writer import LogWriter

EXACT = 1e-9  # values go through 9-decimal files
ENU_TOL_M = 1e-6  # geodetic round trip plus 9-decimal TUM positions
S = 1_000_000_000
T0_NS = 1_700_000_000 * S
ORIGIN = EnuFrame(48.137154, 11.576124, 519.0)
NAVSATFIX = "sensor_msgs/msg/NavSatFix"


def _run(capsys, *args) -> tuple[int, str, str]:
    code = main(["evaluate", *map(str, args)])
    out, err = capsys.readouterr()
    return code, out, err


def _tum(path: Path, stamps, poses) -> Path:
    path.write_text(format_tum(np.asarray(stamps, dtype=np.int64), np.asarray(poses)))
    return path


def _enu_path(n: int) -> np.ndarray:
    t = np.arange(n) * 0.5
    return np.stack([10.0 * np.sin(0.2 * t), 2.0 * t, 0.05 * t], axis=1)


def _gps_bag(path: Path, enu: np.ndarray, no_fix=(), all_invalid: bool = False) -> Path:
    lat, lon, alt = ORIGIN.to_geodetic(enu)
    with LogWriter(path, "ros1") as w:
        w.add_topic("/fix", NAVSATFIX)
        for k in range(len(enu)):
            stamp = T0_NS + k * S // 2
            status = -1 if all_invalid or k in no_fix else 0
            w.write("/fix", stamp, w.make.navsatfix(stamp, "gps", lat[k], lon[k], alt[k], status=status))
    return path


@pytest.fixture
def gps(tmp_path) -> tuple[Path, np.ndarray]:
    """A 12-fix GPS bag around ORIGIN (fixes 0 and 5 without a fix) and the true ENU path."""
    enu = _enu_path(12)
    return _gps_bag(tmp_path / "run.bag", enu, no_fix=(0, 5)), enu


def test_gps_reference_by_hand(capsys, gps, tmp_path):
    bag, enu = gps
    stamps = T0_NS + np.arange(12) * S // 2
    keep = np.array([k not in (0, 5) for k in range(12)])
    # 0.25 m above the GPS antenna, in the frame of the true origin (fix 0 has no fix, so name the origin)
    est = _tum(tmp_path / "est.tum", stamps, [make_pose(so3_exp(np.array([0, 0, 0.1 * k])), p + [0, 0, 0.25])
                                              for k, p in enumerate(enu)])
    code, out, err = _run(capsys, f"{bag}:/fix", est, "--align", "none", "--origin",
                          f"{ORIGIN.lat_deg},{ORIGIN.lon_deg},{ORIGIN.alt_m}", "--json")
    assert code == 0, err
    rep = json.loads(out)
    assert rep["reference"]["kind"] == "gps" and rep["reference"]["position_only"] is True
    assert rep["reference"]["gps"]["messages"] == 12 and rep["reference"]["gps"]["used"] == 10
    assert rep["reference"]["gps"]["dropped_no_fix"] == 2 and rep["reference"]["gps"]["origin_source"] == "given"
    r = rep["estimates"][0]
    assert r["poses"]["matched"] == keep.sum() and r["translation_only"] is True
    assert r["ape"]["trans"]["min"] == pytest.approx(0.25, abs=ENU_TOL_M)
    assert r["ape"]["trans"]["max"] == pytest.approx(0.25, abs=ENU_TOL_M)
    assert r["rpe"]["trans"]["max"] == pytest.approx(0.0, abs=ENU_TOL_M)  # displacements agree exactly
    assert r["ape"]["rot"]["rmse"] is None and r["rpe"]["full"]["max"] is None
    assert "translation metrics only" in err
    assert ("GPS /fix: 10 of 12 fixes used (dropped 2 without a fix); ENU origin 48.13715400, 11.57612400, "
            "519.000 m (given)") in err


def test_gps_reference_with_posyaw_removes_a_heading_and_shift(capsys, gps, tmp_path):
    bag, enu = gps
    stamps = T0_NS + np.arange(12) * S // 2
    T = make_pose(so3_exp(np.array([0, 0, 0.8])), np.array([5.0, -3.0, 1.0]))
    est = _tum(tmp_path / "est.tum", stamps, [T @ make_pose(t=p) for p in enu])
    code, out, err = _run(capsys, f"{bag}:/fix", est, "--align", "posyaw", "--json")
    assert code == 0, err
    r = json.loads(out)["estimates"][0]
    assert r["alignment"]["mode"] == "posyaw"
    # origin at the first valid fix (fix 1): ENU axes there differ from ORIGIN's by ~1e-7 rad over 2 m
    assert r["ape"]["trans"]["max"] < 1e-5
    code, _, err = _run(capsys, f"{bag}:/fix", est, "--align", "origin")
    assert code == 2 and err.strip() == (f"lio: error: --align origin needs orientations, and {bag}:/fix or {est} "
                                         f"has positions only (GPS); use se3, sim3, scale, posyaw or none")


def test_gps_errors_exit_2(capsys, tmp_path, gps):
    bag = _gps_bag(tmp_path / "bad.bag", _enu_path(3), all_invalid=True)
    est = _tum(tmp_path / "est.tum", [T0_NS, T0_NS + S], [np.eye(4), np.eye(4)])
    code, _, err = _run(capsys, f"{bag}:/fix", est)
    assert code == 2 and err.strip() == (f"lio: error: {bag}: topic /fix: no valid fix among its 3 NavSatFix "
                                         f"messages (3 without a fix (status NO_FIX), 0 with NaN or out-of-range "
                                         f"coordinates)")
    for origin, message in (("48.1,11.5", "--origin '48.1,11.5' is not LAT,LON,ALT (degrees, degrees, metres), e.g. 48.1,11.5,520"),
                            ("95,11.5,0", "--origin '95,11.5,0': latitude 95 outside -90..90 deg")):
        code, _, err = _run(capsys, f"{gps[0]}:/fix", est, "--origin", origin)
        assert code == 2 and err.strip() == f"lio: error: {message}"
    code, _, err = _run(capsys, est, est, "--origin", "48,11,500")
    assert code == 2 and err.strip() == (f"lio: error: --origin applies to GPS (NavSatFix) topics, and neither {est} "
                                         f"nor an estimate is one")


def _motion(t: np.ndarray) -> np.ndarray:
    pos = np.stack([20 * np.sin(0.05 * t), 12 * np.sin(0.1 * t) + 0.3 * t, 1.5 * np.sin(0.2 * t)], axis=1)
    P = np.repeat(np.eye(4)[None], len(t), axis=0)
    P[:, :3, :3] = so3_exp(np.stack([0.2 * np.sin(0.3 * t), 0.15 * np.cos(0.25 * t), 0.4 * t], axis=1))
    P[:, :3, 3] = pos
    return P


def test_estimate_offset_recovers_a_shift(capsys, tmp_path):
    t_ref = np.arange(0, 40, 0.01)
    gt = _tum(tmp_path / "gt.tum", T0_NS + np.round(t_ref * 1e9).astype(np.int64), _motion(t_ref))
    t_est = np.arange(0.5, 39.5, 0.05)
    est = _tum(tmp_path / "est.tum", T0_NS + np.round((t_est - 0.137) * 1e9).astype(np.int64), _motion(t_est))
    code, out, err = _run(capsys, gt, est, "--estimate-offset", "--interpolate", "--json")
    assert code == 0, err
    r = json.loads(out)["estimates"][0]
    assert r["time_offset"]["offset_s"] == pytest.approx(0.137, abs=1e-4)  # noise-free: far inside 1 ms
    assert r["association"]["t_offset_s"] == r["time_offset"]["offset_s"]
    assert r["ape"]["trans"]["rmse"] < 1e-3
    assert json.loads(out)["metrics"][0]["t_offset_s"] == r["time_offset"]["offset_s"]
    assert f"time offset {est}: +0.1369" in err or f"time offset {est}: +0.1370" in err


def test_offset_errors_exit_2(capsys, tmp_path):
    gt = _tum(tmp_path / "gt.tum", np.arange(0, 11) * S, [make_pose(t=[k, 0, 0]) for k in range(11)])
    est = _tum(tmp_path / "est.tum", np.arange(100, 111) * S, [make_pose(t=[k, 0, 0]) for k in range(11)])
    code, _, err = _run(capsys, gt, est, "--estimate-offset", "--offset-range", "-1,1")
    assert code == 2 and err.strip() == (
        f"lio: error: --estimate-offset: no offset in -1..1 s pairs any stamp of {est} with one of {gt} within "
        f"--t-max-diff 0.01 s; offsets in -110.01..-89.99 s overlap their time ranges (the midpoints meet at -100 s): "
        f"widen --offset-range")
    for args, message in (
        (["--offset-range", "-1,1"], "--offset-range needs --estimate-offset"),
        (["--estimate-offset", "--t-offset", "2"], "give --t-offset or --estimate-offset, not both"),
        (["--estimate-offset", "--offset-range", "1"], "--offset-range '1' is not LO,HI in seconds (e.g. -0.5,0.5)"),
        (["--estimate-offset", "--offset-range", "1,-1"], "--offset-range '1,-1': LO must be below HI"),
    ):
        code, _, err = _run(capsys, gt, est, *args)
        assert code == 2 and err.strip() == f"lio: error: {message}", args


@pytest.fixture
def runs(tmp_path) -> tuple[Path, list[Path]]:
    """A straight reference and four estimates shifted sideways by 0.1, 0.3 (lio) and 0.2, 0.6 m (kiss)."""
    stamps = (np.arange(20) * S // 10 + T0_NS).astype(np.int64)
    ref = [make_pose(t=[0.5 * k, 0.1 * k * k, 0]) for k in range(20)]
    gt = _tum(tmp_path / "gt.tum", stamps, ref)
    ests = []
    for name, dy in (("lio_1", 0.1), ("lio_2", 0.3), ("kiss_1", 0.2), ("kiss_2", 0.6)):
        ests.append(_tum(tmp_path / f"{name}.tum", stamps, [p @ make_pose(t=[0, 0, dy]) for p in ref]))
    return gt, ests


def test_groups_give_mean_std_min_max(capsys, runs):
    gt, (l1, l2, k1, k2) = runs
    code, out, err = _run(capsys, gt, "--group", f"lio={l1},{l2}", "--group", f"kiss={k1},{k2}", "--align", "none",
                          "--json")
    assert code == 0, err
    rep = json.loads(out)
    assert [e["estimate"] for e in rep["estimates"]] == [str(l1), str(l2), str(k1), str(k2)]
    lio, kiss = rep["groups"]
    assert lio["group"] == "lio" and lio["n"] == 2 and lio["runs"] == [str(l1), str(l2)]
    s = lio["metrics"]["ape_trans_rmse"]  # the APE is the sideways shift at every pose
    assert s["mean"] == pytest.approx(0.2, abs=EXACT) and s["std"] == pytest.approx(math.sqrt(0.02), abs=EXACT)
    assert (s["min"], s["max"]) == (pytest.approx(0.1, abs=EXACT), pytest.approx(0.3, abs=EXACT))
    assert kiss["metrics"]["ape_trans_rmse"]["mean"] == pytest.approx(0.4, abs=EXACT)
    assert "statistics over runs" in err
    code, out, _ = _run(capsys, gt, l1, l2, k1, k2, "--group-by", r"^([a-z]+)_\d", "--align", "none", "--csv", "-")
    assert code == 0
    rows = list(csv.DictReader(io.StringIO(out)))
    assert list(rows[0])[:4] == ["estimate", "group", "statistic", "matches"]
    assert [(r["estimate"], r["group"], r["statistic"]) for r in rows] == [
        (str(l1), "lio", "run"), (str(l2), "lio", "run"), (str(k1), "kiss", "run"), (str(k2), "kiss", "run"),
        *(("", g, st) for g in ("lio", "kiss") for st in ("mean", "std", "min", "max"))]
    assert float(rows[5]["ape_trans_max"]) == pytest.approx(math.sqrt(0.02), abs=EXACT)  # lio std of 0.1, 0.3
    assert float(rows[9]["ape_trans_max"]) == pytest.approx(math.sqrt(0.08), abs=EXACT)  # kiss std of 0.2, 0.6


def test_group_errors_exit_2(capsys, runs):
    gt, (l1, l2, k1, _) = runs
    code, _, err = _run(capsys, gt, "--group", f"lio={l1},{l2}", "--group", f"kiss={k1}")
    assert code == 2 and err.strip() == f"lio: error: group 'kiss' has one run ({k1}); statistics over runs need at least two"
    code, _, err = _run(capsys, gt, l1, l2, k1, "--group-by", r"^([a-z]+)_")
    assert code == 2 and err.strip() == f"lio: error: group 'kiss' has one run ({k1}); statistics over runs need at least two"
    code, _, err = _run(capsys, gt, "--group", "lio")
    assert code == 2 and "--group 'lio' is not NAME=EST[,EST...]" in err
    code, _, err = _run(capsys, gt)
    assert code == 2 and err.strip() == "lio: error: give at least one estimate (EST arguments or --group NAME=EST,...)"


def test_plots_for_gps_offset_and_groups(capsys, gps, tmp_path):
    bag, enu = gps
    stamps = T0_NS + np.arange(12) * S // 2
    rng = np.random.default_rng(2)
    ests = []
    for k in range(2):
        poses = [make_pose(t=p + rng.normal(0, 0.05, 3)) for p in enu]
        ests.append(_tum(tmp_path / f"run_{k}.tum", stamps + 40_000_000, poses))
    plots = tmp_path / "plots"
    code, _, err = _run(capsys, f"{bag}:/fix", *ests, "--align", "posyaw", "--estimate-offset", "--interpolate",
                        "--t-max-diff", "0.1", "--group", "runs=run_*.tum", "--plot", plots, "--quiet")
    assert code == 0, err
    for name in ("top_view.png", "ape.png", "rpe_histogram.png", "offset.png", "groups.png"):
        data = (plots / name).read_bytes()
        assert data[:8] == b"\x89PNG\r\n\x1a\n" and len(data) > 10_000, name
    metrics = json.loads((plots / "metrics.json").read_text())
    assert metrics["groups"][0]["runs"] == [str(e) for e in ests]
    code, _, err = _run(capsys, f"{bag}:/fix", *ests, "--align", "posyaw", "--estimate-offset", "--interpolate",
                        "--t-max-diff", "0.1", "--plot", plots)
    assert code == 2 and "already exists; pass --force to overwrite it" in err


def test_a_far_origin_is_warned_about(capsys, gps, tmp_path):
    bag, enu = gps
    est = _tum(tmp_path / "est.tum", T0_NS + np.arange(12) * S // 2, [make_pose(t=p) for p in enu])
    code, _, err = _run(capsys, f"{bag}:/fix", est, "--align", "posyaw", "--origin", "48.5,11.576124,519")
    assert code == 0, err  # 40 km north of the fixes: the ENU axes there tilt by 0.36 deg
    assert f"lio: warning: {bag}:/fix: fixes lie up to 40 km from the ENU origin, whose axes tilt by 0.36 deg" in err


def test_gps_as_an_estimate(capsys, gps, tmp_path):
    bag, enu = gps
    stamps = T0_NS + np.arange(12) * S // 2
    T = make_pose(so3_exp(np.array([0, 0, -0.4])), np.array([1.0, 2.0, 0.0]))
    gt = _tum(tmp_path / "gt.tum", stamps, [T @ make_pose(so3_exp(np.array([0, 0, 0.2 * k])), p)
                                            for k, p in enumerate(enu)])
    code, out, err = _run(capsys, gt, f"{bag}:/fix", "--align", "posyaw", "--json")
    assert code == 0, err
    r = json.loads(out)["estimates"][0]
    assert r["translation_only"] is True and r["gps"]["used"] == 10 and r["ape"]["rot"]["max"] is None
    assert r["ape"]["trans"]["max"] < 1e-5  # the ENU frame at fix 1 is a yaw and a shift away
