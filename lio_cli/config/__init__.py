"""Typed configuration: one pydantic model per command, loaded from YAML, overridden by flags field by field.

``load_model`` reads a YAML mapping and validates it into a model; ``with_overrides`` applies flags (dotted field
names, ``None`` meaning "not given"); ``dump_model`` writes the YAML a run leaves beside its outputs, which
loads back into the same model.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any, ClassVar, TypeVar

import yaml
import math

from pydantic import BaseModel, ConfigDict, ValidationError, ValidationInfo, field_validator

from ..errors import ConfigError
from ..model.calibration import Calibration

M = TypeVar("M", bound=BaseModel)

MAX_MAGNITUDE = 1e9  # larger than any physical setting lio has (s, m, Hz, noise densities), far below overflow
# upper bounds of integer fields (every int field has one: a huge count overflows kiss-icp's C++ ints)
MAX_ITERATIONS = 10_000  # ICP iterations per scan
MAX_THREADS = 1024
MAX_POINTS = 10_000_000  # points of one scan
MAX_EVERY = 1000  # "every n-th scan" schedules
MAX_COUNT = 1_000_000  # counts of scans or messages
_RANGE_ERRORS = ("greater_than", "greater_than_equal", "less_than", "less_than_equal")


def _numbers(value: Any):
    if isinstance(value, float):
        yield value
    elif isinstance(value, (list, tuple)):
        for v in value:
            yield from _numbers(v)
    elif isinstance(value, dict):
        for v in value.values():
            yield from _numbers(v)


class Strict(BaseModel):
    """Base of every config model: unknown keys are errors, not silently ignored."""

    model_config = ConfigDict(extra="forbid")
    # fields whose size is their own range's business, not MAX_MAGNITUDE's (a clock offset between an epoch clock
    # and one counting from boot is 1.6e9 s)
    unbounded_fields: ClassVar[frozenset[str]] = frozenset()

    @field_validator("*", mode="after")
    @classmethod
    def _finite(cls, value: Any, info: ValidationInfo) -> Any:
        """Every number is finite and of a physical size: NaN, inf or 1e300 in a config is a typo, not a setting
        (they would overflow stamps or turn the filter's covariance to NaN)."""
        for v in _numbers(value):
            if not math.isfinite(v):
                raise ValueError(f"must be a finite number, got {v}")
            if abs(v) > MAX_MAGNITUDE and info.field_name not in cls.unbounded_fields:
                raise ValueError(f"{v:g} is out of range (|value| <= {MAX_MAGNITUDE:g})")
        return value


def read_mapping(path: Path, what: str) -> dict:
    """A YAML file's top-level mapping; every failure is a ConfigError naming the file."""
    try:
        data = yaml.safe_load(Path(path).read_text()) or {}
    except FileNotFoundError as err:
        raise ConfigError(f"{path}: no such {what} file") from err
    except (OSError, yaml.YAMLError, UnicodeDecodeError) as err:
        raise ConfigError(f"{path}: cannot read {what} ({str(err).splitlines()[0]})") from err
    if not isinstance(data, dict):
        raise ConfigError(f"{path}: {what} must be a mapping of option: value")
    return data


def validate(model: type[M], data: dict, where: str) -> M:
    """``data`` as ``model``; the first validation problem becomes one ConfigError line naming the field."""
    try:
        return model.model_validate(data)
    except ValidationError as err:
        first = err.errors()[0]
        loc = ".".join(str(x) for x in first["loc"])
        msg = first["msg"].removeprefix("Value error, ")
        if first["type"] in _RANGE_ERRORS:
            msg = f"must be {field_range(model, first['loc'])}, got {first['input']}"
        raise ConfigError(f"{where}: {loc}: {msg}" if loc else f"{where}: {msg}") from err


def field_range(model: type[BaseModel], loc: tuple) -> str:
    """The allowed range of the field at ``loc`` (nested models followed, list indices skipped) in words:
    "within [1, 1000]", "> 0", "<= 4"."""
    info, current = None, model
    for part in loc:
        if isinstance(part, int) or current is None:
            continue
        info = current.model_fields.get(part)
        if info is None:
            break
        ann = info.annotation
        args = [a for a in getattr(ann, "__args__", ()) if isinstance(a, type) and issubclass(a, BaseModel)]
        current = ann if isinstance(ann, type) and issubclass(ann, BaseModel) else (args[0] if args else None)
    low = high = None
    for m in [] if info is None else info.metadata:
        for attr, sign in (("gt", ">"), ("ge", ">=")):
            if getattr(m, attr, None) is not None:
                low = (sign, getattr(m, attr))
        for attr, sign in (("lt", "<"), ("le", "<=")):
            if getattr(m, attr, None) is not None:
                high = (sign, getattr(m, attr))
    if low and high:
        return f"{'[' if low[0] == '>=' else '('}{low[1]:g}, {high[1]:g}{']' if high[0] == '<=' else ')'}".join(
            ("within ", ""))
    bound = low or high
    return "in range" if bound is None else f"{bound[0]} {bound[1]:g}"


def load_model(model: type[M], path: Path | None, what: str = "config") -> M:
    """Defaults, updated from a YAML file when given."""
    if path is None:
        return model()
    return validate(model, read_mapping(path, what), str(path))


def with_overrides(cfg: M, overrides: dict[str, Any], where: str = "options") -> M:
    """A copy of ``cfg`` with each given field (dotted name -> value, None = not given) replaced, re-validated."""
    data = cfg.model_dump()
    for dotted, value in overrides.items():
        if value is None:
            continue
        node = data
        *parents, leaf = dotted.split(".")
        for key in parents:
            node = node.setdefault(key, {})
        node[leaf] = value
    return validate(type(cfg), data, where)


def dump_model(cfg: BaseModel) -> str:
    return yaml.safe_dump(cfg.model_dump(mode="json"), sort_keys=False)


def load_calibration(path: Path) -> Calibration:
    return validate(Calibration, read_mapping(path, "calibration"), str(path))


__all__ = ["MAX_COUNT", "MAX_EVERY", "MAX_ITERATIONS", "MAX_POINTS", "MAX_THREADS", "Strict", "field_range", "dump_model", "load_calibration", "load_model", "read_mapping", "validate", "with_overrides"]


def load_config(model: type[M], config: Path | None, calib: Path | None = None, calib_field: str = "calibration") -> M:
    """A command's configuration: defaults, then the ``config`` file's fields, then the ``calib`` file's fields
    (under ``calib_field``) replacing them one by one, as ``--config`` and ``--calib`` combine everywhere."""
    cfg = load_model(model, config)
    if calib is None:
        return cfg
    cal = load_calibration(calib)
    return with_overrides(cfg, {f"{calib_field}.{k}": v for k, v in cal.model_dump(exclude_unset=True).items()})

