"""Point maps as PLY and PCD files."""

import numpy as np
import pytest

from lio_cli.errors import ConfigError
from lio_cli.io.files.point_clouds import read_point_map, write_point_map


@pytest.mark.parametrize("suffix", [".ply", ".pcd"])
def test_maps_round_trip_with_standard_headers(tmp_path, suffix):
    pts = np.random.default_rng(0).normal(size=(123, 3)).astype(np.float32)
    path = tmp_path / f"map{suffix}"
    write_point_map(path, pts)
    np.testing.assert_array_equal(read_point_map(path), pts)
    head = path.read_bytes()[:200]
    assert (b"element vertex 123" in head) if suffix == ".ply" else (b"POINTS 123\nDATA binary" in head)
    with pytest.raises(Exception, match="already exists"):
        write_point_map(path, pts)


def test_other_suffixes_are_refused(tmp_path):
    with pytest.raises(ConfigError, match=r"map.xyz: a map is written as \.ply or \.pcd"):
        write_point_map(tmp_path / "map.xyz", np.zeros((1, 3)))
    assert not (tmp_path / "map.xyz").exists()
