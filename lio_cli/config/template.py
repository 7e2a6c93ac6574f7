"""A configuration model's defaults as YAML with a comment above every field (its description), as ``lio config``
prints them; the text loads back into the same defaults."""

from __future__ import annotations

import inspect
import textwrap
from typing import Any

import yaml
from pydantic import BaseModel

_WIDTH = 100  # of a comment line, indentation included


def field_doc(model: type[BaseModel], name: str) -> str:
    """A field's description; a nested model without one is described by its class's first docstring line."""
    info = model.model_fields[name]
    if info.description:
        return info.description
    value = info.default
    if isinstance(value, BaseModel):
        doc = inspect.getdoc(type(value)) or ""
        return doc.split("\n\n")[0].replace("\n", " ").replace("``", "")
    return ""


def _comment(text: str, indent: str) -> list[str]:
    if not text:
        return []
    return textwrap.wrap(text, width=_WIDTH, initial_indent=f"{indent}# ", subsequent_indent=f"{indent}# ",
                         break_on_hyphens=False, break_long_words=False)


def _scalar(name: str, value: Any, indent: str) -> list[str]:
    text = yaml.safe_dump({name: value}, sort_keys=False, default_flow_style=True, width=10**6).strip()
    return [indent + text.removeprefix("{").removesuffix("}")]


def _lines(cfg: BaseModel, indent: str) -> list[str]:
    out: list[str] = []
    for name in type(cfg).model_fields:
        value = getattr(cfg, name)
        out += _comment(field_doc(type(cfg), name), indent)
        if isinstance(value, BaseModel):
            out.append(f"{indent}{name}:")
            out += _lines(value, indent + "  ")
        else:
            out += _scalar(name, cfg.model_dump(mode="json", include={name})[name], indent)
    return out


def commented_yaml(cfg: BaseModel, header: str = "") -> str:
    """``cfg`` as YAML, every field preceded by a comment saying what it is; ``header`` (comment lines) first."""
    head = [line for text in header.splitlines() for line in (_comment(text, "") or ["#"])]
    return "\n".join(head + _lines(cfg, "")) + "\n"


__all__ = ["commented_yaml", "field_doc"]
