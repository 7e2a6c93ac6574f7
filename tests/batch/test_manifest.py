"""``lio_cli.batch.manifest``: defaults and runs merged, globs expanded, paths resolved, ground-truth patterns."""

from __future__ import annotations

from pathlib import Path

import pytest

from lio_cli.batch.commands import resolve_config
from lio_cli.batch.manifest import expand, flatten, load_manifest, shorthand
from lio_cli.errors import ConfigError

REPO = Path(__file__).resolve().parents[2]


def _manifest(tmp_path: Path, text: str):
    path = tmp_path / "m.yaml"
    path.write_text(text)
    return expand(load_manifest(path), tmp_path, str(path))


def test_flatten_nested_and_dotted_options():
    assert flatten({"fusion": {"method": "ekf", "imu": {"gyro_noise_radps": 1e-3}}, "registration.threads": 1,
                    "prior": "imu", "use": {}}) == {
        "fusion.method": "ekf", "fusion.imu.gyro_noise_radps": 1e-3, "registration.threads": 1, "prior": "imu",
        "use": {}}


def test_defaults_runs_globs_and_paths(tmp_path):
    (tmp_path / "logs").mkdir()
    for name in ("b.bag", "a.bag", "c.mcap"):
        (tmp_path / "logs" / name).write_bytes(b"")
    specs = _manifest(tmp_path, """\
output: out
defaults:
  gt: "{dir}/{stem}.gt.tum"
  group: all
  config: odom.yaml
  calib: calib.yaml
  options: {prior: constant-velocity, fusion: {method: complementary}}
runs:
  - log: logs/*.bag
  - log: ./logs/../logs/c.mcap
    name: car
    group: null
    gt: /ground_truth
    options: {fusion.alpha: 0.5}
  - log: logs/a.bag
    name: a_fused
    command: fuse
    options: {estimator: planar}
""")
    assert [(s.name, s.command, s.group) for s in specs] == [
        ("a", "odom", "all"), ("b", "odom", "all"), ("car", "odom", None), ("a_fused", "fuse", "all")]
    logs = tmp_path / "logs"
    assert [s.log for s in specs] == [logs / "a.bag", logs / "b.bag", logs / "c.mcap", logs / "a.bag"]
    assert specs[0].gt == str(logs / "a.gt.tum") and specs[2].gt == "/ground_truth"
    assert specs[0].options == {"prior": "constant-velocity", "fusion.method": "complementary"}
    assert specs[2].options == {"prior": "constant-velocity", "fusion.method": "complementary", "fusion.alpha": 0.5}
    assert specs[3].options == {"estimator": "planar"}  # the defaults' options and config file are odom's
    assert [s.config for s in specs] == [tmp_path / "odom.yaml"] * 3 + [None]
    assert [s.calib for s in specs] == [tmp_path / "calib.yaml"] * 4
    (tmp_path / "odom.yaml").write_text("max_gap_s: 2.5\n")
    (tmp_path / "calib.yaml").write_text("imu_time_offset_s: 0.01\n")
    cfg = resolve_config(specs[2])
    assert (cfg.max_gap_s, cfg.calibration.imu_time_offset_s) == (2.5, 0.01)
    assert (cfg.prior, cfg.fusion.method, cfg.fusion.alpha) == ("constant-velocity", "complementary", 0.5)
    assert resolve_config(specs[3]).estimator == "planar"


def test_shorthand_is_a_manifest_with_defaults(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    for name in ("x.bag", "y.bag"):
        Path(name).write_bytes(b"")
    m = shorthand("odom", ["*.bag"], "/ground_truth", "g", None, None, {"prior": "none"})
    specs = expand(m, tmp_path, "lio batch")
    assert [(s.name, s.gt, s.group, s.options) for s in specs] == [
        ("x", "/ground_truth", "g", {"prior": "none"}), ("y", "/ground_truth", "g", {"prior": "none"})]
    with pytest.raises(ConfigError, match="^batch runs odom, fuse, deskew, calibrate, not 'evaluate'$"):
        shorthand("evaluate", ["*.bag"], None, None, None, None, {})


def test_one_name_for_a_glob_is_refused(tmp_path):
    for name in ("x.bag", "y.bag"):
        (tmp_path / name).write_bytes(b"")
    with pytest.raises(ConfigError) as err:
        _manifest(tmp_path, "runs:\n  - log: '*.bag'\n    name: both\n")
    assert str(err.value) == (f"{tmp_path / 'm.yaml'}: runs[0]: name: one name for 2 logs matched by '*.bag'; "
                              "drop the name (each run is named after its log), give a pattern such as "
                              "'{parent}_{stem}', or list the logs one by one")


def test_an_unknown_placeholder_in_a_run_name_is_refused(tmp_path):
    """'{nope}' was taken literally: a run folder named 'x_{nope}'."""
    (tmp_path / "x.bag").write_bytes(b"")
    with pytest.raises(ConfigError) as err:
        _manifest(tmp_path, "runs:\n  - log: x.bag\n    name: '{parent}_{nope}_{Stem}'\n")
    assert str(err.value) == (f"{tmp_path / 'm.yaml'}: runs[0]: name: {{Stem}}, {{nope}} are no placeholders (run names "
                              "take {stem} and {parent}, the log's folder name)")


@pytest.mark.parametrize("name, why", [
    ('"a\\0b"', "'a\\x00b' holds a control character (a newline, tab or NUL); run names are folder names"),
    ('"a\\nb"', "'a\\nb' holds a control character (a newline, tab or NUL); run names are folder names"),
    ("x" * 300, "'" + "x" * 40 + "...' is 300 bytes long; a run name takes at most 200"),
    ("'.hidden'", "'.hidden' cannot name a run folder"),
])
def test_a_run_name_that_cannot_name_a_folder_is_refused_before_any_run(tmp_path, name, why):
    """Issue 32: a NUL, a newline or 300 characters failed the run as 'internal' after the batch started."""
    (tmp_path / "x.bag").write_bytes(b"")
    with pytest.raises(ConfigError) as err:
        _manifest(tmp_path, f"runs:\n  - log: x.bag\n    name: {name}\n")
    assert str(err.value) == f"{tmp_path / 'm.yaml'}: runs[0]: name: {why}"


@pytest.mark.parametrize("field, what", [("calib", "calibration"), ("config", "config")])
def test_a_missing_file_names_the_manifest_and_run(tmp_path, field, what):
    """It said only "/.../nope.yaml: no such calibration file", without the manifest or the run naming it."""
    (tmp_path / "x.bag").write_bytes(b"")
    (spec,) = _manifest(tmp_path, f"runs:\n  - log: x.bag\n    command: odom\n    {field}: nope.yaml\n")
    with pytest.raises(ConfigError) as err:
        resolve_config(spec)
    assert str(err.value) == f"{tmp_path / 'm.yaml'}: runs[0]: {tmp_path / 'nope.yaml'}: no such {what} file"


def test_logs_of_one_name_in_several_folders_are_named_by_pattern(tmp_path):
    """'seqs/*/data.bag' (one recording per folder, each data.bag): the shorthand could not run it at all, a
    manifest only with every log listed by hand."""
    for seq in ("s1", "s2"):
        (tmp_path / "seqs" / seq).mkdir(parents=True)
        (tmp_path / "seqs" / seq / "data.bag").write_bytes(b"")
    with pytest.raises(ConfigError) as err:
        expand(shorthand("odom", ["seqs/*/data.bag"], None, None, None, None, {}), tmp_path, "lio batch")
    assert str(err.value).endswith("set name: on one of them, or name every run by its folder too: name: "
                                   "'{parent}_{stem}' (the shorthand: --name '{parent}_{stem}')")
    m = shorthand("odom", ["seqs/*/data.bag"], None, None, None, None, {}, name="{parent}_{stem}")
    assert [(s.name, s.log.parent.name) for s in expand(m, tmp_path, "lio batch")] == [("s1_data", "s1"), ("s2_data", "s2")]
    specs = _manifest(tmp_path, "runs:\n  - log: 'seqs/*/data.bag'\n    name: 'run_{parent}'\n")
    assert [s.name for s in specs] == ["run_s1", "run_s2"]


def test_the_readme_manifest_expands(tmp_path):
    path = REPO / "docs" / "batch-manifest.yaml"
    m = load_manifest(path)
    specs = expand(m, path.parent, str(path))
    assert [(s.name, s.command, s.group) for s in specs] == [
        ("handheld", "odom", "sample"), ("planar", "odom", "sample"), ("corridor_ros2", "odom", "sample"),
        ("handheld_fused", "fuse", None)]
    assert all(s.log.exists() for s in specs)
    assert specs[3].gt == str(REPO / "sample_logs" / "handheld.gt.tum") and Path(specs[3].gt).exists()
    assert resolve_config(specs[2]).registration.voxel_size_m == 0.5
    assert (path.parent / m.output).resolve() == REPO / "results-manifest"  # covered by .gitignore
