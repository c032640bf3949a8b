"""The layers read one way: no import cycle among the project's modules (every import counts,
those inside functions and under TYPE_CHECKING too); the packages stack model < export <
service and research (the library never imports the export, the service or the research tools;
the export neither of the two above it; the service and the research tools not each other); and
the octree core imports nothing of the project but its base modules."""

from __future__ import annotations

import ast
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
PACKAGES = ("model", "export", "service", "research")
BELOW = {"model": {"model"}, "export": {"model", "export"}, "service": {"model", "export", "service"},
         "research": {"model", "export", "research"}}
"""Package -> the packages its modules may import."""
BASE = {"model.files", "model.formats", "model.cli"}
"""Modules below everything (file writing, format recognition, the command lines' form), importing
nothing of the project."""


def modules() -> dict[str, Path]:
    out = {}
    for pkg in PACKAGES:
        for f in (ROOT / pkg).rglob("*.py"):
            parts = f.relative_to(ROOT).with_suffix("").parts
            out[".".join(parts[:-1] if parts[-1] == "__init__" else parts)] = f
    return out


def import_graph() -> dict[str, set[str]]:
    """Module -> the project modules it imports (a package's ``__init__`` is the package name;
    a module importing its own ancestor package is not an edge)."""
    mods = modules()
    graph: dict[str, set[str]] = {m: set() for m in mods}
    for name, f in mods.items():
        package = name.split(".") if f.name == "__init__.py" else name.split(".")[:-1]
        for node in ast.walk(ast.parse(f.read_text())):
            if isinstance(node, ast.Import):
                targets = [a.name for a in node.names]
            elif isinstance(node, ast.ImportFrom):
                base = node.module or ""
                if node.level:
                    base = ".".join(package[:len(package) - node.level + 1] + ([node.module] if node.module else []))
                targets = [base] + [f"{base}.{a.name}" for a in node.names]
            else:
                continue
            for t in targets:
                while t and t not in mods:
                    t = t.rpartition(".")[0]
                if t and t != name and not name.startswith(t + "."):
                    graph[name].add(t)
    return graph


def cycles(graph: dict[str, set[str]]) -> list[list[str]]:
    """The strongly connected components of more than one module (Tarjan)."""
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    stack: list[str] = []
    on: set[str] = set()
    found: list[list[str]] = []

    def visit(v: str) -> None:
        index[v] = low[v] = len(index)
        stack.append(v)
        on.add(v)
        for w in sorted(graph[v]):
            if w not in index:
                visit(w)
                low[v] = min(low[v], low[w])
            elif w in on:
                low[v] = min(low[v], index[w])
        if low[v] == index[v]:
            comp = []
            while True:
                w = stack.pop()
                on.discard(w)
                comp.append(w)
                if w == v:
                    break
            if len(comp) > 1:
                found.append(sorted(comp))

    for v in sorted(graph):
        if v not in index:
            visit(v)
    return found


def test_no_import_cycles():
    assert cycles(import_graph()) == []


def test_the_cycle_finder_finds_a_cycle():
    assert cycles({"a": {"b"}, "b": {"c"}, "c": {"a"}, "d": {"a"}}) == [["a", "b", "c"]]


def test_the_octree_core_and_the_base_modules_stand_alone():
    """(The octree's command line, ``model.octree.__main__``, is a user of the layers above it.)"""
    graph = import_graph()
    for name, deps in graph.items():
        if name in BASE:
            assert not deps, (name, deps)
        if name.startswith("model.octree") and not name.endswith("__main__"):
            assert all(d.startswith("model.octree") or d in BASE for d in deps), (name, deps)


def test_the_packages_stack_one_way():
    graph = import_graph()
    wrong = [(name, d) for name, deps in graph.items() for d in deps
             if d.split(".")[0] not in BELOW[name.split(".")[0]]]
    assert wrong == []
