"""Point maps as files: binary little-endian PLY or binary PCD (x y z float32), written atomically."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from ...errors import ConfigError
from .atomic import atomic_output

MAP_SUFFIXES = (".ply", ".pcd")


def check_map_suffix(path: Path) -> None:
    if Path(path).suffix.lower() not in MAP_SUFFIXES:
        raise ConfigError(f"{path}: a map is written as .ply or .pcd; name the file with one of those suffixes")


def point_map_bytes(points: np.ndarray, suffix: str) -> bytes:
    """The file content of ``points`` (N,3) as PLY or PCD."""
    pts = np.ascontiguousarray(points, dtype="<f4").reshape(-1, 3)
    n = len(pts)
    if suffix.lower() == ".ply":
        head = ("ply\nformat binary_little_endian 1.0\ncomment written by lio\n"
                f"element vertex {n}\nproperty float x\nproperty float y\nproperty float z\nend_header\n")
    else:
        head = ("# .PCD v0.7 - written by lio\nVERSION 0.7\nFIELDS x y z\nSIZE 4 4 4\nTYPE F F F\nCOUNT 1 1 1\n"
                f"WIDTH {n}\nHEIGHT 1\nVIEWPOINT 0 0 0 1 0 0 0\nPOINTS {n}\nDATA binary\n")
    return head.encode("ascii") + pts.tobytes()


def write_point_map(path: Path, points: np.ndarray, force: bool = False) -> None:
    path = Path(path)
    check_map_suffix(path)
    with atomic_output(path, force) as tmp:
        tmp.write_bytes(point_map_bytes(points, path.suffix))


def read_point_map(path: Path) -> np.ndarray:
    """Points (N,3) of a PLY or PCD file written by ``write_point_map``."""
    data = Path(path).read_bytes()
    marker = b"end_header\n" if Path(path).suffix.lower() == ".ply" else b"DATA binary\n"
    body = data[data.index(marker) + len(marker):]
    return np.frombuffer(body, dtype="<f4").reshape(-1, 3)
