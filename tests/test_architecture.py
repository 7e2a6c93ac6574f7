"""The house rules of docs/architecture.md, checked on the source: layers, no import cycle, no private name
imported across modules, no mixins in the odometry, no prefix families outside a package."""

from __future__ import annotations

import ast
from collections import Counter, defaultdict
from pathlib import Path

import pytest

import lio_cli

ROOT = Path(lio_cli.__file__).resolve().parent


def _module(path: Path) -> str:
    parts = list(path.relative_to(ROOT.parent).with_suffix("").parts)
    return ".".join(parts[:-1] if parts[-1] == "__init__" else parts)


MODULES = {_module(p): p for p in sorted(ROOT.rglob("*.py"))}


def _imports(name: str) -> list[tuple[str, list[str], int]]:
    """(imported module, names taken from it, line) for every import in a module, at any depth."""
    path = MODULES[name]
    package = name if path.name == "__init__.py" else name.rpartition(".")[0]
    out = []
    for node in ast.walk(ast.parse(path.read_text())):
        if isinstance(node, ast.Import):
            out += [(a.name, [], node.lineno) for a in node.names]
        elif isinstance(node, ast.ImportFrom):
            base = node.module or ""
            if node.level:
                anchor = package.split(".")[: len(package.split(".")) - node.level + 1]
                base = ".".join(anchor + ([base] if base else []))
            out.append((base, [a.name for a in node.names], node.lineno))
    return out


def _targets(name: str) -> set[str]:
    """The lio_cli modules a module imports (a name that is a submodule counts as that module)."""
    found = set()
    for base, names, _ in _imports(name):
        subs = [f"{base}.{n}" for n in names if f"{base}.{n}" in MODULES]
        found.update(subs or ([base] if base in MODULES else []))
    return found - {name}


def test_core_imports_no_io_plots_jobs_or_ui():
    bad = [(m, base) for m in MODULES if m.startswith("lio_cli.core")
           for base, _, _ in _imports(m)
           if base.split(".")[0] in ("matplotlib", "typer", "rich")
           or base.startswith(("lio_cli.io", "lio_cli.plots", "lio_cli.jobs", "lio_cli.cli", "lio_cli.batch"))]
    assert bad == []


def test_matplotlib_only_in_plots():
    bad = [m for m in MODULES if not m.startswith("lio_cli.plots")
           for base, _, _ in _imports(m) if base.split(".")[0] == "matplotlib"]
    assert bad == []


def test_no_import_cycle():
    graph = {m: _targets(m) for m in MODULES}
    # a package's face may name its submodules; a submodule importing its own package's face is the cycle we forbid
    cycles, state = [], {}

    def visit(m: str, stack: list[str]) -> None:
        state[m] = 1
        for t in sorted(graph[m]):
            if state.get(t) == 1:
                cycles.append(stack[stack.index(t):] + [t])
            elif t not in state:
                visit(t, stack + [t])
        state[m] = 2

    for m in sorted(graph):
        if m not in state:
            visit(m, [m])
    assert cycles == []


def test_no_private_name_across_modules():
    bad = [(m, line, n) for m in MODULES for base, names, line in _imports(m)
           if base.startswith("lio_cli") for n in names if n.startswith("_") and not n.startswith("__")]
    assert bad == []


def test_odometry_has_no_mixins():
    bad = []
    for m, path in MODULES.items():
        if m.startswith("lio_cli.core.odometry"):
            for node in ast.walk(ast.parse(path.read_text())):
                if isinstance(node, ast.ClassDef) and len(node.bases) > 1:
                    bad.append((m, node.name))
    assert bad == []


@pytest.mark.parametrize("folder", sorted({p.parent for p in ROOT.rglob("*.py")}), ids=lambda p: str(p.relative_to(ROOT.parent)))
def test_no_prefix_family_outside_a_package(folder: Path):
    """Three modules of one folder sharing a prefix are a package waiting to be made."""
    prefixes = Counter(p.stem.split("_")[0] for p in folder.glob("*.py") if p.stem != "__init__")
    assert [p for p, n in prefixes.items() if n >= 3] == []
