"""TUM text written a block of lines at a time: the same bytes whatever the block, read back to the same poses."""

from __future__ import annotations

import numpy as np
import pytest

from lio_cli.geometry import pose_from_xyz_quat
from lio_cli.io.files.trajectory import format_tum, read_tum, tum_blocks


def _poses(n: int) -> tuple[np.ndarray, np.ndarray]:
    rng = np.random.default_rng(3)
    q = rng.normal(size=(n, 4))
    q /= np.linalg.norm(q, axis=1, keepdims=True)
    q[q[:, 3] < 0] *= -1
    stamps = 1_700_000_000_000_000_000 + np.arange(n, dtype=np.int64) * 100_000_001
    return stamps, pose_from_xyz_quat(rng.normal(scale=50, size=(n, 3)), q)


def test_known_lines():
    poses = np.stack([np.eye(4), np.eye(4)])
    poses[1, :3, 3] = [1.5, -2.25, 1e-10]
    poses[1, :3, :3] = [[0, -1, 0], [1, 0, 0], [0, 0, 1]]  # 90 deg about z
    text = format_tum(np.array([5, 1_000_000_000_123], np.int64), poses)
    assert text == ("0.000000005 0.000000000 0.000000000 0.000000000 0.000000000 0.000000000 0.000000000 1.000000000\n"
                    "1000.000000123 1.500000000 -2.250000000 0.000000000 0.000000000 0.000000000 0.707106781 "
                    "0.707106781\n")
    assert format_tum(np.zeros(0, np.int64), np.zeros((0, 4, 4))) == ""


@pytest.mark.parametrize("rows", [1, 3, 7, 2048])
def test_blocks_join_to_the_whole_text_and_read_back(tmp_path, rows):
    stamps, poses = _poses(20)
    blocks = list(tum_blocks(stamps, poses, rows))
    assert len(blocks) == -(-20 // rows) and all(b.endswith("\n") for b in blocks)
    text = "".join(blocks)
    assert text == format_tum(stamps, poses) and text.count("\n") == 20
    path = tmp_path / "t.tum"
    path.write_text(text)
    got_ns, got = read_tum(path)
    assert np.array_equal(got_ns, stamps)
    assert np.allclose(got, poses, atol=2e-9)
