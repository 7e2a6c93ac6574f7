"""Trajectory files. TUM: ``stamp tx ty tz qx qy qz qw`` per line, stamp in seconds written from int ns."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from ..errors import InputError
from ..geometry import pose_from_xyz_quat, pose_to_xyz_quat


def format_stamp(ns: int) -> str:
    """Exact decimal seconds of an integer ns stamp (never through a float)."""
    ns = int(ns)
    sign = "-" if ns < 0 else ""
    ns = abs(ns)
    return f"{sign}{ns // 10**9}.{ns % 10**9:09d}"


def parse_stamp_ns(text: str) -> int:
    """Exact integer ns of a decimal seconds string (``1.5``, ``1e9`` style falls back to float)."""
    text = text.strip()
    neg = text.startswith("-")
    body = text.lstrip("+-")
    if body.replace(".", "", 1).isdigit():
        whole, _, frac = body.partition(".")
        frac = (frac + "0" * 9)[:9]
        ns = int(whole or "0") * 10**9 + int(frac)
        return -ns if neg else ns
    value = float(text)  # scientific notation; raises ValueError when not a number
    if not np.isfinite(value):
        raise ValueError(f"non-finite stamp {text}")
    return int(round(value * 1e9))


def format_tum(stamps_ns: np.ndarray, poses: np.ndarray) -> str:
    xyz, q = pose_to_xyz_quat(np.asarray(poses).reshape(-1, 4, 4))
    lines = [
        f"{format_stamp(s)} {p[0]:.9f} {p[1]:.9f} {p[2]:.9f} {r[0]:.9f} {r[1]:.9f} {r[2]:.9f} {r[3]:.9f}"
        for s, p, r in zip(np.asarray(stamps_ns, dtype=np.int64), xyz, q)
    ]
    return "\n".join(lines) + ("\n" if lines else "")


def read_tum(path: str | Path) -> tuple[np.ndarray, np.ndarray]:
    """(stamps_ns (N,), poses (N,4,4)) of a TUM file; bad lines raise InputError with the line number."""
    path = Path(path)
    try:
        text = path.read_text()
    except FileNotFoundError as err:
        raise InputError(f"{path}: no such file") from err
    except (OSError, UnicodeDecodeError) as err:
        raise InputError(f"{path}: cannot read ({err})") from err
    stamps, rows = [], []
    for lineno, line in enumerate(text.splitlines(), start=1):
        line = line.strip()
        if not line or line.startswith("#"):
            continue
        parts = line.replace(",", " ").split()
        if len(parts) != 8:
            raise InputError(f"{path}:{lineno}: expected 8 values (stamp tx ty tz qx qy qz qw), found {len(parts)}")
        try:
            stamp = parse_stamp_ns(parts[0])
            vals = [float(v) for v in parts[1:]]
        except ValueError as err:
            raise InputError(f"{path}:{lineno}: not a number ({err})") from err
        if not np.isfinite(vals).all():
            raise InputError(f"{path}:{lineno}: NaN or infinite value")
        qn = float(np.linalg.norm(vals[3:]))
        if abs(qn - 1.0) > 1e-3:
            raise InputError(f"{path}:{lineno}: quaternion is not unit length (norm {qn:.6f})")
        if stamps and stamp <= stamps[-1]:
            raise InputError(f"{path}:{lineno}: timestamp {parts[0]} is not after the previous line's")
        stamps.append(stamp)
        rows.append(vals)
    if not rows:
        raise InputError(f"{path}: no poses in file")
    arr = np.asarray(rows)
    return np.asarray(stamps, dtype=np.int64), pose_from_xyz_quat(arr[:, :3], arr[:, 3:])
