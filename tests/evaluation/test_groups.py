"""Statistics over runs: group specs, globs, patterns, the one-run refusal and hand-computed statistics."""

from __future__ import annotations

import math

import pytest

from lio_cli.errors import ConfigError, InputError
from lio_cli.evaluation.groups import (
    Group,
    check_groups,
    expand_groups,
    group_statistics,
    groups_by_pattern,
    parse_group,
)

EXACT = 1e-12


def test_parse_group():
    assert parse_group("lio=a.tum, b.tum") == ("lio", ["a.tum", "b.tum"])
    for bad in ("lio", "=a.tum", "lio="):
        with pytest.raises(ConfigError) as err:
            parse_group(bad)
        assert str(err.value) == (f"--group '{bad}' is not NAME=EST[,EST...] (e.g. lio=run1.tum,run2.tum or "
                                  f"lio='lio_*.tum')")


def test_expand_groups_names_globs_and_files(tmp_path):
    for name in ("kiss_1.tum", "kiss_2.tum", "other.tum"):
        (tmp_path / name).write_text("")
    given = [str(tmp_path / "lio_1.tum"), str(tmp_path / "lio_2.tum")]
    groups, all_est = expand_groups(
        [("lio", ["lio_*.tum"]), ("kiss", [str(tmp_path / "kiss_*.tum")]), ("mixed", [given[0], "x.tum"])], given)
    assert [g.members for g in groups] == [given, [str(tmp_path / "kiss_1.tum"), str(tmp_path / "kiss_2.tum")],
                                           [given[0], "x.tum"]]
    assert all_est == [*given, str(tmp_path / "kiss_1.tum"), str(tmp_path / "kiss_2.tum"), "x.tum"]
    for specs, message in (
        ([("a", ["nope_*.tum"])], "--group a: 'nope_*.tum' matches no estimate and no file"),
        ([("a", ["x.tum", "x.tum"])], "--group a: x.tum is listed twice"),
        ([("a", ["x.tum"]), ("a", ["y.tum"])], "--group a: the name is given twice"),
    ):
        with pytest.raises(ConfigError) as err:
            expand_groups(specs, given)
        assert str(err.value) == message


def test_groups_by_pattern_uses_the_first_capture_group():
    est = ["runs/lio_seed1.tum", "runs/lio_seed2.tum", "runs/kiss_seed1.tum", "runs/kiss_seed2.tum", "gt_copy.tum"]
    groups, missed = groups_by_pattern(r"^(\w+?)_seed\d+", est)
    assert [(g.name, g.members) for g in groups] == [("lio", est[:2]), ("kiss", est[2:4])]
    assert missed == ["gt_copy.tum"]
    groups, _ = groups_by_pattern(r"seed\d", est)  # no capture group: the match names the group
    assert [g.name for g in groups] == ["seed1", "seed2"]
    with pytest.raises(ConfigError) as err:
        groups_by_pattern("(", est)
    assert str(err.value).startswith("--group-by '(' is not a regular expression (")
    with pytest.raises(ConfigError) as err:
        groups_by_pattern("zzz", est)
    assert str(err.value) == "--group-by 'zzz' matches none of the estimates' file names"


def test_a_group_of_one_run_is_refused():
    check_groups([Group("a", ["1.tum", "2.tum"])])
    with pytest.raises(InputError) as err:
        check_groups([Group("a", ["1.tum", "2.tum"]), Group("b", ["3.tum"])])
    assert str(err.value) == "group 'b' has one run (3.tum); statistics over runs need at least two"


def test_statistics_by_hand():
    metrics = {
        "a": {"ape_rmse": 1.0, "matches": 10, "kitti_trans_pct": None},
        "b": {"ape_rmse": 2.0, "matches": 12, "kitti_trans_pct": 1.5},
        "c": {"ape_rmse": 4.0, "matches": 11, "kitti_trans_pct": None},
    }
    (g,) = group_statistics([Group("g", ["a", "b", "c"])], metrics)
    s = g.metrics["ape_rmse"]
    assert s["n"] == 3 and s["min"] == 1.0 and s["max"] == 4.0
    assert s["mean"] == pytest.approx(7 / 3, abs=EXACT)
    # sample std: squared deviations 16/9 + 1/9 + 25/9 = 42/9, over n - 1 = 2
    assert s["std"] == pytest.approx(math.sqrt(42 / 18), abs=EXACT)
    assert g.metrics["matches"]["mean"] == 11.0 and g.metrics["matches"]["std"] == 1.0
    assert g.metrics["kitti_trans_pct"] == {"n": 1, "mean": 1.5, "std": None, "min": 1.5, "max": 1.5}
    assert g.summary() == {"group": "g", "runs": ["a", "b", "c"], "n": 3, "metrics": g.metrics}
