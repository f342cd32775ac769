"""No import circle among the modules of servogym.chips (issue 23, point 6).

The graph counts every import statement, also those inside functions (a lazy import still
ties two modules together). A family package imports servogym.chips._base, never the
registry (servogym.chips._family); the registry imports the family packages.
"""

from __future__ import annotations

import ast
import subprocess
import sys
from pathlib import Path

import pytest

CHIPS = Path(__file__).resolve().parents[2] / "servogym" / "chips"


def _module_name(path: Path) -> str:
    parts = path.relative_to(CHIPS.parent.parent).with_suffix("").parts
    return ".".join(parts[:-1] if parts[-1] == "__init__" else parts)


def _modules() -> dict[str, Path]:
    return {_module_name(p): p for p in sorted(CHIPS.rglob("*.py"))}


def _imports(path: Path, name: str, known: set[str]) -> set[str]:
    """The chips modules ``path`` imports (``from pkg import mod`` counts ``pkg.mod``)."""
    package = name if path.name == "__init__.py" else name.rpartition(".")[0]
    out = set()
    for node in ast.walk(ast.parse(path.read_text())):
        if isinstance(node, ast.Import):
            targets = [alias.name for alias in node.names]
        elif isinstance(node, ast.ImportFrom):
            base = node.module or ""
            if node.level:
                anchor = package.rsplit(".", node.level - 1)[0] if node.level > 1 else package
                base = f"{anchor}.{base}" if base else anchor
            # ``from pkg import mod`` imports the module pkg.mod; ``from mod import name``, mod
            subs = [f"{base}.{alias.name}" for alias in node.names]
            targets = [s for s in subs if s in known] or [base]
        else:
            continue
        out.update(t for t in targets if t in known)
    out.discard(name)
    return out


def _graph() -> dict[str, set[str]]:
    modules = _modules()
    known = set(modules)
    return {name: _imports(path, name, known) for name, path in modules.items()}


def _cycles(graph: dict[str, set[str]]) -> list[list[str]]:
    """Strongly connected components with more than one module (Tarjan)."""
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    stack: list[str] = []
    on_stack: set[str] = set()
    out = []

    def visit(v: str) -> None:
        index[v] = low[v] = len(index)
        stack.append(v)
        on_stack.add(v)
        for w in graph[v]:
            if w not in index:
                visit(w)
                low[v] = min(low[v], low[w])
            elif w in on_stack:
                low[v] = min(low[v], index[w])
        if low[v] == index[v]:
            component = []
            while True:
                w = stack.pop()
                on_stack.discard(w)
                component.append(w)
                if w == v:
                    break
            if len(component) > 1:
                out.append(sorted(component))

    for v in graph:
        if v not in index:
            visit(v)
    return out


def test_the_graph_sees_the_imports():
    graph = _graph()
    assert "servogym.chips.pmd" in graph["servogym.chips._family"]
    assert "servogym.chips._base" in graph["servogym.chips.pmd._family"]
    assert "servogym.chips._registers" in graph["servogym.chips.pmd._params"]


def test_a_circle_is_found():
    graph = {"a": {"b"}, "b": {"c"}, "c": {"a"}, "d": {"a"}}
    assert _cycles(graph) == [["a", "b", "c"]]


def test_no_import_circle_in_chips():
    assert _cycles(_graph()) == []


def test_families_do_not_import_the_registry():
    graph = _graph()
    for name, imported in graph.items():
        if name.count(".") >= 3 or name.rpartition(".")[2] in ("pmd", "pmac", "parker6k"):
            assert "servogym.chips._family" not in imported, name


FIRST_IMPORTS = [
    "servogym._files",  # imports servogym.chips; the families' exporters import it
    "servogym.chips._family",
    *(
        f"servogym.chips.{f}.{m}"
        for f in ("pmd", "pmac", "parker6k")
        for m in ("_family", "_export")
    ),
]


@pytest.mark.parametrize("module", FIRST_IMPORTS)
def test_module_imports_first(module):
    """The module imports first in a fresh interpreter (no order-dependent circle)."""
    done = subprocess.run(
        [sys.executable, "-c", f"import {module}"], capture_output=True, text=True, timeout=120
    )
    assert done.returncode == 0, done.stderr[-2000:]
