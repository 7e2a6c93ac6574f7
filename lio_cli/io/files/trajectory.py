"""Trajectory text formats.

TUM: ``stamp tx ty tz qx qy qz qw`` per line, stamp in seconds written from int ns.
KITTI: 12 values per line, the row-major 3x4 matrix ``[R | t]`` of ``T_world_body``; stamps come from a
separate times file (one stamp in seconds per line, as KITTI's ``times.txt``) or a fixed rate.
Every problem is an ``InputError`` naming the file and the line.
"""

from __future__ import annotations

from collections.abc import Iterator
from pathlib import Path

import numpy as np

from ...errors import InputError
from ...geometry import pose_from_xyz_quat, pose_to_xyz_quat

_INT64_MAX = np.iinfo(np.int64).max
# Quaternions further than this from unit length are rejected (TUM files written with 6 decimals are ~1e-6 off).
QUAT_NORM_TOL = 1e-3
# KITTI rotation blocks further than this from orthonormal are rejected.
KITTI_ORTHO_TOL = 1e-3
TUM_BLOCK_ROWS = 2048  # lines formatted into one string at a time (about 200 kB)
STAMP_UNITS_NS = {"s": 1, "ms": 10**3, "us": 10**6, "ns": 10**9}  # divisor applied to the seconds parse


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
    return "".join(tum_blocks(stamps_ns, poses))


def tum_blocks(stamps_ns: np.ndarray, poses: np.ndarray, rows: int = TUM_BLOCK_ROWS) -> Iterator[str]:
    """TUM lines of poses (N,4,4) at ``stamps_ns``, ``rows`` lines a string: a long trajectory's text is
    written without being held whole."""
    xyz, q = pose_to_xyz_quat(np.asarray(poses).reshape(-1, 4, 4))
    stamps = np.asarray(stamps_ns, dtype=np.int64)
    for lo in range(0, len(stamps), rows):
        hi = lo + rows
        yield "".join(
            f"{format_stamp(s)} {p[0]:.9f} {p[1]:.9f} {p[2]:.9f} {r[0]:.9f} {r[1]:.9f} {r[2]:.9f} {r[3]:.9f}\n"
            for s, p, r in zip(stamps[lo:hi].tolist(), xyz[lo:hi].tolist(), q[lo:hi].tolist())
        )


def format_kitti(poses: np.ndarray) -> str:
    """KITTI pose lines (row-major 3x4) of poses (N,4,4)."""
    rows = np.asarray(poses, dtype=np.float64).reshape(-1, 4, 4)[:, :3, :].reshape(-1, 12)
    return "".join(" ".join(f"{v:.9e}" for v in r) + "\n" for r in rows)


def read_text(path: Path) -> str:
    try:
        return path.read_text()
    except FileNotFoundError as err:
        raise InputError(f"{path}: no such file") from err
    except IsADirectoryError as err:
        raise InputError(f"{path}: is a folder, not a trajectory file") from err
    except (OSError, UnicodeDecodeError) as err:
        raise InputError(f"{path}: cannot read ({err})") from err


def _data_rows(text: str) -> Iterator[tuple[int, list[str]]]:
    """(1-based line number, tokens) of each non-empty, non-comment line."""
    for lineno, line in enumerate(text.splitlines(), start=1):
        line = line.strip()
        if line and not line.startswith("#"):
            yield lineno, line.replace(",", " ").split()


def _data_lines(text: str) -> tuple[list[int], list[list[str]]]:
    """(1-based line numbers, tokens) of the non-empty, non-comment lines."""
    rows = list(_data_rows(text))
    return [n for n, _ in rows], [t for _, t in rows]


def _unit_hint(path: Path, lineno: int, text: str, what: str, unit: str = "s") -> InputError:
    finer = " or ".join(u for u, d in STAMP_UNITS_NS.items() if d > STAMP_UNITS_NS[unit])
    if unit == "ns":  # nothing finer: no unit makes it a time
        return InputError(f"{path}:{lineno}: {what} {text} is beyond what int64 nanoseconds hold (year 2262); it is no "
                          "time stamp in any unit")
    if unit != "s":  # read in the unit asked for: a finer one is what the file holds
        return InputError(
            f"{path}:{lineno}: {what} {text} is too large for {unit} (beyond year 2262); the file's stamps look "
            f"like {finer}: give that unit (--gt-stamp-unit/--est-stamp-unit)"
        )
    return InputError(
        f"{path}:{lineno}: {what} {text} is too large for seconds (beyond year 2262); the file's stamps look "
        f"like ms, us or ns, and TUM stamps are seconds: write them so (lio evaluate also reads other units with "
        f"--gt-stamp-unit/--est-stamp-unit)"
    )


def _stamps_ns(path: Path, numbers: list[int], texts: list[str], unit: str) -> np.ndarray:
    divisor = STAMP_UNITS_NS[unit]
    out = np.empty(len(texts), dtype=np.int64)
    for k, (lineno, text) in enumerate(zip(numbers, texts)):
        try:
            ns = parse_stamp_ns(text)
        except (ValueError, OverflowError) as err:
            raise InputError(f"{path}:{lineno}: stamp '{text}' is not a number") from err
        ns //= divisor
        if abs(ns) > _INT64_MAX:
            raise _unit_hint(path, lineno, text, "stamp", unit)
        out[k] = ns
    return out


def _check_increasing(path: Path, numbers: list[int], stamps_ns: np.ndarray, texts: list[str]) -> None:
    bad = np.flatnonzero(np.diff(stamps_ns) <= 0)
    if len(bad):
        k = int(bad[0]) + 1
        what = "repeats" if stamps_ns[k] == stamps_ns[k - 1] else "goes backwards from"
        raise InputError(
            f"{path}:{numbers[k]}: timestamp {texts[k]} {what} the previous line's ({texts[k - 1]}); "
            f"stamps must increase strictly"
        )


def _floats(path: Path, numbers: list[int], rows: list[list[str]]) -> np.ndarray:
    try:
        return np.array(rows, dtype=np.float64)
    except ValueError:
        for lineno, row in zip(numbers, rows):
            for v in row:
                try:
                    float(v)
                except ValueError as err:
                    raise InputError(f"{path}:{lineno}: '{v}' is not a number") from err
        raise  # pragma: no cover - np.array failed, yet every value parses


def _check_finite(path: Path, numbers: list[int], vals: np.ndarray) -> None:
    bad = np.flatnonzero(~np.isfinite(vals).all(axis=1))
    if len(bad):
        raise InputError(f"{path}:{numbers[int(bad[0])]}: NaN or infinite value")


def _fast_table(text: str, ncols: int) -> tuple[list[str], np.ndarray] | None:
    """(first-column tokens, all values as float (N, ncols)) of a plain machine-written table, else None.

    Plain means: no comments, commas or blank lines, ``ncols`` numbers on every line. Anything else (or any
    doubt) returns None and the caller takes the line-by-line path, which names the offending line.
    """
    if "#" in text or "," in text or "\n\n" in text.strip() or text[:1].isspace():
        return None
    tokens = text.split()
    n = text.strip().count("\n") + 1 if tokens else 0
    if n == 0 or len(tokens) != n * ncols:
        return None
    import warnings

    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # a bad token stops fromstring early (older numpy warns, newer raises)
        try:
            vals = np.fromstring(text, dtype=np.float64, sep=" ")
        except ValueError:
            return None
    if len(vals) != n * ncols:
        return None
    return tokens[::ncols], vals.reshape(n, ncols)


def _fast_stamps_ns(texts: list[str], unit: str) -> np.ndarray | None:
    """Exact int ns of plain decimal stamps (``123.456``), or None if any is signed, scientific or too large."""
    out = []
    append = out.append
    try:
        for s in texts:
            whole, _, frac = s.partition(".")
            if len(frac) > 9 or not (whole.isdigit() and (frac.isdigit() or not frac)):
                return None
            append(int(whole) * 1_000_000_000 + (int(frac) * 10 ** (9 - len(frac)) if frac else 0))
    except ValueError:
        return None
    divisor = STAMP_UNITS_NS[unit]
    if divisor != 1:
        out = [v // divisor for v in out]
    if max(out) > _INT64_MAX:
        return None  # the line-by-line path names the line and the unit flag
    return np.array(out, dtype=np.int64)


def _rows(path: Path, text: str, columns: int, layout: str) -> tuple[list[int], list[list[str]]]:
    """Line numbers and tokens of the data lines, each checked to hold ``columns`` values."""
    numbers, tokens = _data_lines(text)
    if not tokens:
        raise InputError(f"{path}: no poses in file")
    for lineno, parts in zip(numbers, tokens):
        if len(parts) != columns:
            raise InputError(f"{path}:{lineno}: expected {columns} values ({layout}), found {len(parts)}")
    return numbers, tokens


def read_tum(path: str | Path, stamp_unit: str = "s", text: str | None = None) -> tuple[np.ndarray, np.ndarray]:
    """(stamps_ns (N,), poses (N,4,4)) of a TUM file; bad lines raise InputError with the line number.

    ``stamp_unit`` (s, ms, us, ns) says what the first column counts; seconds are parsed exactly. ``text``:
    the file's content when already read (a pipe can be read only once).
    """
    path = Path(path)
    text = read_text(path) if text is None else text
    fast = _fast_table(text, 8)
    stamps = _fast_stamps_ns(fast[0], stamp_unit) if fast is not None else None
    if fast is not None and stamps is not None:
        texts = fast[0]
        numbers = range(1, len(texts) + 1)
        vals = fast[1][:, 1:]
    else:
        numbers, tokens = _rows(path, text, 8, "stamp tx ty tz qx qy qz qw")
        texts = [p[0] for p in tokens]
        stamps = _stamps_ns(path, numbers, texts, stamp_unit)
        vals = _floats(path, numbers, [p[1:] for p in tokens])
    _check_finite(path, numbers, vals)
    with np.errstate(over="ignore"):  # a component of 1e300: its norm is inf, and refused below
        qn = np.linalg.norm(vals[:, 3:], axis=1)
    bad = np.flatnonzero(np.abs(qn - 1.0) > QUAT_NORM_TOL)
    if len(bad):
        k = int(bad[0])
        raise InputError(f"{path}:{numbers[k]}: quaternion is not unit length (norm {qn[k]:.6f})")
    _check_increasing(path, numbers, stamps, texts)
    return stamps, pose_from_xyz_quat(vals[:, :3], vals[:, 3:])


def read_kitti(path: str | Path, text: str | None = None) -> np.ndarray:
    """Poses (N,4,4) of a KITTI pose file (12 values per line: row-major [R | t]); ``text`` as for read_tum."""
    path = Path(path)
    text = read_text(path) if text is None else text
    fast = _fast_table(text, 12)
    if fast is not None:
        numbers, vals = range(1, len(fast[1]) + 1), fast[1]
    else:
        numbers, tokens = _rows(path, text, 12, "KITTI row-major 3x4 pose")
        vals = _floats(path, numbers, tokens)
    _check_finite(path, numbers, vals)
    poses = np.zeros((len(vals), 4, 4))
    poses[:, :3, :] = vals.reshape(-1, 3, 4)
    poses[:, 3, 3] = 1.0
    R = poses[:, :3, :3]
    ortho = np.abs(np.einsum("nji,njk->nik", R, R) - np.eye(3)).max(axis=(1, 2))
    bad = np.flatnonzero((ortho > KITTI_ORTHO_TOL) | (np.linalg.det(R) <= 0.0))
    if len(bad):
        k = int(bad[0])
        raise InputError(f"{path}:{numbers[k]}: the 3x3 block is not a rotation (|R^T R - I| = {ortho[k]:.2e})")
    return poses


def read_times(path: str | Path) -> np.ndarray:
    """Stamps (int64 ns) of a KITTI times file: one stamp in seconds per line."""
    path = Path(path)
    numbers, tokens = _data_lines(read_text(path))
    if not tokens:
        raise InputError(f"{path}: no stamps in file")
    for lineno, parts in zip(numbers, tokens):
        if len(parts) != 1:
            raise InputError(f"{path}:{lineno}: expected one stamp per line, found {len(parts)} values")
    texts = [p[0] for p in tokens]
    stamps = _stamps_ns(path, numbers, texts, "s")
    _check_increasing(path, numbers, stamps, texts)
    return stamps


def sniff_columns(path: str | Path, text: str) -> int:
    """Number of values on the first data line of a text trajectory (8 TUM, 12 KITTI), ``text`` its content."""
    for _, tokens in _data_rows(text):
        return len(tokens)
    raise InputError(f"{Path(path)}: no poses in file")
