"""A batch manifest: which logs, which command on each, with which options, and where the results go.

```yaml
output: results/            # the output root (relative paths: from the manifest's folder)
defaults:                   # every run's, unless the run says otherwise
  command: odom             # odom | fuse | deskew | calibrate
  gt: /ground_truth         # a topic of each log, a TUM/KITTI file, or a pattern: "{dir}/{stem}.gt.tum"
  options: {prior: imu}     # fields of its configuration (as its .config.yaml), dotted or nested; runs of
                            # another command take only their own options
runs:
  - log: logs/walk.bag
    group: handheld         # runs of a group get mean/std/min/max of every metric
  - log: logs/drive_*.mcap  # a glob: one run per match
    group: drive
    options: {registration.voxel_size_m: 0.5}
```

``load_manifest`` validates it (every problem one ``ConfigError`` line naming the file and the place, exit 2);
``shorthand`` builds the same model for ``lio batch odom 'logs/*.bag' --gt /ground_truth -O results/``.
``expand`` turns a manifest into one ``RunSpec`` per run, paths absolute, options merged and flattened.
"""

from __future__ import annotations

import glob
import os
import re
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Literal, Optional

from pydantic import Field, ValidationError

from ..config import Strict, read_mapping
from ..errors import ConfigError
from ..jobs.outputs import log_stem

Command = Literal["odom", "fuse", "deskew", "calibrate"]
BATCH_COMMANDS = ("odom", "fuse", "deskew", "calibrate")
_GLOB_CHARS = set("*?[")


class RunEntry(Strict):
    """One entry of ``runs:``; a ``log`` with glob characters stands for one run per matching path."""

    log: str
    command: Optional[Command] = None
    name: Optional[str] = Field(None, description="the run's folder under the output root; default: the log's stem; "
                                "{stem} and {parent} (the log's folder name) stand for parts of each log's path")
    group: Optional[str] = None
    gt: Optional[str] = None
    config: Optional[str] = Field(None, description="a YAML configuration file of the command (as --config)")
    calib: Optional[str] = Field(None, description="a calibration YAML (as --calib)")
    options: dict[str, Any] = Field(default_factory=dict)


class Defaults(Strict):
    command: Command = "odom"
    name: Optional[str] = Field(None, description="every run's folder name, with {stem} and {parent}")
    group: Optional[str] = None
    gt: Optional[str] = None
    config: Optional[str] = None
    calib: Optional[str] = None
    options: dict[str, Any] = Field(default_factory=dict)


class Manifest(Strict):
    output: Optional[str] = None
    defaults: Defaults = Field(default_factory=Defaults)
    runs: list[RunEntry] = Field(min_length=1)


@dataclass(frozen=True)
class RunSpec:
    """One run, resolved: absolute paths, the command, its flat options (dotted field -> value)."""

    index: int  # position in the batch
    where: str  # "MANIFEST: runs[i]" for messages
    name: str
    command: str
    log: Path
    group: str | None
    gt: str | None
    config: Path | None
    calib: Path | None
    options: dict[str, Any]


def _validate(data: dict, where: str) -> Manifest:
    """``data`` as a Manifest; the first problem is one ConfigError line, runs named ``runs[i]``."""
    try:
        return Manifest.model_validate(data)
    except ValidationError as err:
        first = err.errors()[0]
        loc = "".join(f"[{x}]" if isinstance(x, int) else f".{x}" for x in first["loc"]).lstrip(".")
        loc = re.sub(r"^(runs\[\d+\])\.", r"\1: ", loc)
        msg = first["msg"].removeprefix("Value error, ")
        raise ConfigError(f"{where}: {loc}: {msg}" if loc else f"{where}: {msg}") from err


def load_manifest(path: Path) -> Manifest:
    return _validate(read_mapping(path, "manifest"), str(path))


def shorthand(command: str, patterns: list[str], gt: str | None, group: str | None, config: str | None,
              calib: str | None, options: dict[str, Any], name: str | None = None) -> Manifest:
    """The manifest ``lio batch COMMAND 'PATTERN'... [--gt ...] [--set k=v]`` stands for."""
    if command not in BATCH_COMMANDS:
        raise ConfigError(f"batch runs {', '.join(BATCH_COMMANDS)}, not '{command}'")
    if not patterns:
        raise ConfigError(f"lio batch {command}: give one or more logs or glob patterns")
    data = {"defaults": {"command": command, "name": name, "gt": gt, "group": group, "config": config, "calib": calib,
                         "options": options},
            "runs": [{"log": p} for p in patterns]}
    return _validate(data, "options")


def flatten(options: dict[str, Any], prefix: str = "") -> dict[str, Any]:
    """``{"fusion": {"method": "ekf"}, "registration.threads": 1}`` -> dotted keys to leaf values."""
    flat: dict[str, Any] = {}
    for key, value in options.items():
        dotted = f"{prefix}{key}"
        if isinstance(value, dict) and value:
            flat.update(flatten(value, dotted + "."))
        else:
            flat[dotted] = value
    return flat


def _path(text: str | None, base: Path) -> Path | None:
    if text is None:
        return None
    return Path(os.path.abspath(base / Path(text).expanduser()))  # absolute, '..' removed, links kept


def _logs(pattern: str, base: Path, where: str) -> list[Path]:
    path = _path(pattern, base)
    if not _GLOB_CHARS & set(pattern):
        return [path]
    found = sorted(Path(p) for p in glob.glob(str(path)))
    if not found:
        raise ConfigError(f"{where}: log: '{pattern}' matches no file or folder")
    return found


def gt_for(gt: str | None, log: Path, base: Path) -> str | None:
    """A run's ground truth: a topic of the log (``/name`` that is no file) or an absolute file path;
    ``{stem}`` and ``{dir}`` stand for the log's stem and folder."""
    if gt is None:
        return None
    text = gt.replace("{stem}", log_stem(log)).replace("{dir}", str(log.parent))
    if text.startswith("/"):
        return text  # an absolute file, or a topic of the log: decided where the run runs, as lio odom does
    return str(_path(text, base))


_NAME_KEYS = ("{stem}", "{parent}")


MAX_NAME_BYTES = 200  # a folder name holds 255 bytes; the partial folder adds '.' and '.partial-' and 12 hex digits


def _check_name(name: str, at: str) -> None:
    """A run name that can name its folder (and its partial folder) on any file system lio writes to."""
    shown = name.encode("unicode_escape").decode("ascii")  # a newline or NUL shown as \n, \x00
    if not name or name.startswith(".") or "/" in name or name in ("summary.csv", "summary.json"):
        raise ConfigError(f"{at}: name: '{shown}' cannot name a run folder")
    if any(ord(c) < 32 or ord(c) == 127 for c in name):
        raise ConfigError(f"{at}: name: '{shown}' holds a control character (a newline, tab or NUL); "
                          "run names are folder names")
    if len(name.encode("utf-8", "surrogateescape")) > MAX_NAME_BYTES:
        raise ConfigError(f"{at}: name: '{shown[:40]}...' is {len(name.encode('utf-8', 'surrogateescape'))} bytes "
                          f"long; a run name takes at most {MAX_NAME_BYTES}")


def _run_name(pattern: str | None, log: Path) -> str:
    """A run's folder name: the log's stem, or ``pattern`` with {stem} and {parent} (the log's folder) filled in
    (logs of one name in several folders: 'seqs/*/data.bag' with '{parent}_{stem}')."""
    if pattern is None:
        return log_stem(log)
    return pattern.replace("{stem}", log_stem(log)).replace("{parent}", log.parent.name)


def expand(manifest: Manifest, base: Path, where: str) -> list[RunSpec]:
    """One ``RunSpec`` per run (globs expanded); run names must be unique (they are folders)."""
    d = manifest.defaults
    specs: list[RunSpec] = []
    seen: dict[str, str] = {}
    for i, entry in enumerate(manifest.runs):
        at = f"{where}: runs[{i}]"
        logs = _logs(entry.log, base, at)
        pattern = entry.name if entry.name is not None else d.name
        unknown = sorted(set(re.findall(r"\{[^{}]*\}", pattern or "")) - set(_NAME_KEYS))
        if unknown:  # it was taken literally: a folder 'hh_{nope}'
            what = "is no placeholder" if len(unknown) == 1 else "are no placeholders"
            raise ConfigError(f"{at}: name: {', '.join(unknown)} {what} (run names take {{stem}} and {{parent}}, the "
                              "log's folder name)")
        if pattern is not None and len(logs) > 1 and not any(k in pattern for k in _NAME_KEYS):
            raise ConfigError(f"{at}: name: one name for {len(logs)} logs matched by '{entry.log}'; "
                              "drop the name (each run is named after its log), give a pattern such as "
                              "'{parent}_{stem}', or list the logs one by one")
        command = entry.command or d.command
        # the defaults' options are fields of the defaults' command: other commands' runs take only their own
        options = {**(flatten(d.options) if command == d.command else {}), **flatten(entry.options)}

        def pick(key: str, entry: RunEntry = entry):  # the run's value when it gives one (null included)
            return getattr(entry, key) if key in entry.model_fields_set else getattr(d, key)

        for log in logs:
            name = _run_name(pattern, log)
            _check_name(name, at)
            if name in seen:
                raise ConfigError(f"{at}: two runs are named '{name}' ({seen[name]} and {log}); "
                                  "set name: on one of them, or name every run by its folder too: name: "
                                  "'{parent}_{stem}' (the shorthand: --name '{parent}_{stem}')")
            seen[name] = str(log)
            gt = pick("gt")
            if command == "deskew" and "gt" not in entry.model_fields_set:
                gt = None  # the defaults' ground truth is for the runs that estimate a trajectory
            config = pick("config") if command == d.command else entry.config  # a config file is one command's
            specs.append(RunSpec(
                index=len(specs), where=at, name=name, command=command, log=log, group=pick("group"),
                gt=gt_for(gt, log, base), config=_path(config, base), calib=_path(pick("calib"), base),
                options=options))
    return specs


__all__ = ["BATCH_COMMANDS", "Defaults", "Manifest", "RunEntry", "RunSpec", "expand", "flatten", "gt_for",
           "load_manifest", "shorthand"]
