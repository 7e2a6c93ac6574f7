"""commented_yaml: a model's defaults as YAML with a comment above every field, loading back into the defaults."""

from __future__ import annotations

import re

import pytest
import yaml

from lio_cli.config import load_model
from lio_cli.config.calibrate import CalibrateConfig
from lio_cli.config.deskew import DeskewConfig
from lio_cli.config.fuse import FuseConfig
from lio_cli.config.odom import OdomConfig
from lio_cli.config.template import commented_yaml

MODELS = [OdomConfig, DeskewConfig, FuseConfig, CalibrateConfig]
KEY = re.compile(r"^(\s*)([A-Za-z_][A-Za-z0-9_]*):")


@pytest.mark.parametrize("model", MODELS, ids=lambda m: m.__name__)
def test_the_text_loads_back_into_the_defaults(model, tmp_path):
    path = tmp_path / "c.yaml"
    path.write_text(commented_yaml(model(), "header"))
    assert load_model(model, path) == model()
    assert yaml.safe_load(path.read_text()) == model().model_dump(mode="json")


@pytest.mark.parametrize("model", MODELS, ids=lambda m: m.__name__)
def test_every_field_has_a_comment_above_it(model):
    lines = commented_yaml(model()).splitlines()
    keys = [(i, m) for i, line in enumerate(lines) if (m := KEY.match(line))]
    assert len(keys) > 40
    for i, m in keys:
        above = lines[i - 1]
        assert above.startswith(m.group(1) + "# ") and len(above) > len(m.group(1)) + 3, (lines[i - 1], lines[i])
    assert max(len(line) for line in lines if line.lstrip().startswith("#")) <= 100


def test_a_long_description_wraps_and_a_nested_model_takes_its_class_doc():
    text = commented_yaml(OdomConfig())
    assert "# kiss-icp registration and voxel map.\nregistration:\n  # map voxel size;" in text
    assert "# a time gap up to this long that the IMU covers is bridged:" in text  # max_bridge_s, two lines
    i = text.index("max_bridge_s: 3.0")
    assert text[:i].rstrip().splitlines()[-2].startswith("# a time gap up to this long")


def test_the_header_is_comment_lines_and_values_keep_their_types():
    text = commented_yaml(FuseConfig(), "first line\nsecond line")
    assert text.startswith("# first line\n# second line\n")
    data = yaml.safe_load(text)
    assert data["estimator"] == "auto" and data["smooth"] is True and data["rate_hz"] is None
    assert data["noise"]["gyro_noise_density"] == pytest.approx(1e-3)
