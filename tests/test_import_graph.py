"""The import graph of the project's Python (issue 33 item 3): folders import only downwards, and no module imports
itself back through others.

Folders, lowest first: ``flexarm`` (the physics library) < ``fmus`` (FMU sources) < ``fmu_build`` (build code) <
``scenarios`` (the master and the runs) < ``benchmarks``. Every import counts, those inside functions too: a lazy
import still makes the importing module depend on the imported one.
"""

from __future__ import annotations

import ast
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
FOLDERS = ("flexarm", "fmus", "fmu_build", "scenarios", "benchmarks")


def _modules() -> dict[str, Path]:
    mods = {}
    for folder in FOLDERS:
        for path in sorted((ROOT / folder).rglob("*.py")):
            parts = list(path.relative_to(ROOT).with_suffix("").parts)
            mods[".".join(parts[:-1] if parts[-1] == "__init__" else parts)] = path
    return mods


def import_graph() -> dict[str, set[str]]:
    """Module -> the project's modules it imports (the longest known prefix of each imported name)."""
    mods = _modules()

    def known(name: str) -> str | None:
        while name and name not in mods:
            name = name.rpartition(".")[0]
        return name or None

    graph = {}
    for mod, path in mods.items():
        package = mod if path.name == "__init__.py" else mod.rpartition(".")[0]
        out = set()
        for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"))):
            if isinstance(node, ast.Import):
                out.update(filter(None, (known(a.name) for a in node.names)))
            elif isinstance(node, ast.ImportFrom):
                base = node.module or ""
                if node.level:
                    parts = package.split(".")
                    base = ".".join(parts[:len(parts) - node.level + 1] + ([node.module] if node.module else []))
                for a in node.names:  # `from pkg import module` imports the module, `from mod import name` the mod
                    target = known(f"{base}.{a.name}") if f"{base}.{a.name}" in mods else known(base)
                    if target:
                        out.add(target)
        out.discard(mod)
        graph[mod] = out
    return graph


def cycles(graph: dict[str, set[str]]) -> list[list[str]]:
    """The strongly connected components with more than one module (Tarjan), each sorted."""
    index, low, stack, on, found, counter = {}, {}, [], set(), [], [0]

    def visit(v):
        index[v] = low[v] = counter[0]
        counter[0] += 1
        stack.append(v)
        on.add(v)
        for w in graph[v]:
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

    for v in graph:
        if v not in index:
            visit(v)
    return found


def upward_imports(graph: dict[str, set[str]]) -> list[str]:
    """Every import of a module from a folder above its own (``importer -> imported``), sorted."""
    rank = {f: i for i, f in enumerate(FOLDERS)}
    return sorted(f"{m} -> {t}" for m, out in graph.items() for t in out
                  if rank[t.split(".")[0]] > rank[m.split(".")[0]])


def test_folders_import_only_downwards():
    assert upward_imports(import_graph()) == []


def test_no_import_circle_between_modules():
    assert cycles(import_graph()) == []


def test_the_checks_can_fail():
    """A made-up graph with a circle and an upward import is caught; lazy imports inside functions count."""
    graph = {"flexarm.a": {"flexarm.b"}, "flexarm.b": {"flexarm.a", "scenarios.x"}, "scenarios.x": set()}
    assert cycles(graph) == [["flexarm.a", "flexarm.b"]]
    assert upward_imports(graph) == ["flexarm.b -> scenarios.x"]
    assert "fmu_build.native_build" in import_graph()["fmu_build.native"]  # imported inside a function there
