"""No import cycles between packages: every import counts, the lazy ones inside functions included.

A unit is a top-level package (``bags``, ``msg_adapters``, ``sgs_slam_ros``) or one subpackage or
top-level module of ``sgs_slam_core`` (``sgs_slam_core.slam``, ``sgs_slam_core.errors``, ...). Read
from the source with ``ast``, so an import hidden in a function cannot hide a cycle.
"""

from __future__ import annotations

import ast
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
PACKAGES = ("sgs_slam_core", "sgs_slam_ros", "msg_adapters", "bags")


def unit_of(module: str) -> str | None:
    """The unit a dotted module name belongs to, or None outside the packages."""
    parts = module.split(".")
    if parts[0] not in PACKAGES:
        return None
    if parts[0] == "sgs_slam_core" and len(parts) > 1:
        return ".".join(parts[:2])
    return parts[0]


def module_name(path: Path) -> str:
    rel = path.relative_to(ROOT).with_suffix("")
    parts = list(rel.parts)
    if parts[-1] == "__init__":
        parts.pop()
    return ".".join(parts)


def is_module(name: str) -> bool:
    """True when the dotted name is a module or package of this repository."""
    path = ROOT.joinpath(*name.split("."))
    return path.with_suffix(".py").is_file() or (path / "__init__.py").is_file()


def imported_modules(path: Path) -> set[str]:
    """Every module ``path`` imports, at any depth of its code (``from a import b``: ``a.b`` if a module, else a)."""
    tree = ast.parse(path.read_text(), str(path))
    name = module_name(path)
    package = name if path.name == "__init__.py" else name.rpartition(".")[0]
    found: set[str] = set()
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            found.update(alias.name for alias in node.names)
        elif isinstance(node, ast.ImportFrom):
            base = node.module or ""
            if node.level:
                anchor = package.split(".")[: len(package.split(".")) - node.level + 1]
                base = ".".join([*anchor, base] if base else anchor)
            for alias in node.names:  # a submodule counts as itself, a name as its module
                found.add(f"{base}.{alias.name}" if is_module(f"{base}.{alias.name}") else base)
    return found


def unit_graph() -> dict[str, set[str]]:
    """Unit -> the units it imports (itself excluded)."""
    graph: dict[str, set[str]] = {}
    for package in PACKAGES:
        for path in (ROOT / package).rglob("*.py"):
            unit = unit_of(module_name(path))
            assert unit is not None
            deps = {unit_of(m) for m in imported_modules(path)} - {None, unit}
            graph.setdefault(unit, set()).update(d for d in deps if d is not None)
    return graph


def cycles(graph: dict[str, set[str]]) -> list[list[str]]:
    """Strongly connected components with more than one unit (Tarjan)."""
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    stack: list[str] = []
    on_stack: set[str] = set()
    found: list[list[str]] = []

    def visit(v: str) -> None:
        index[v] = low[v] = len(index)
        stack.append(v)
        on_stack.add(v)
        for w in sorted(graph.get(v, ())):
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
                found.append(sorted(component))

    for v in sorted(graph):
        if v not in index:
            visit(v)
    return found


def test_the_checker_sees_a_cycle():
    assert cycles({"a": {"b"}, "b": {"c"}, "c": {"a"}, "d": {"a"}}) == [["a", "b", "c"]]
    assert cycles({"a": {"b"}, "b": set()}) == []


def test_no_package_imports_another_that_imports_it_back():
    graph = unit_graph()
    assert "sgs_slam_core.slam" in graph and "sgs_slam_core.render" in graph["sgs_slam_core.slam"]
    found = cycles(graph)
    detail = [" <-> ".join(c) + ": " + "; ".join(f"{u} imports {sorted(graph[u] & set(c))}" for u in c) for c in found]
    assert not found, "\n".join(detail)
